"""Binary PLY bodies, a whole column at a time, both ways, and the list-property helpers the
ASCII body shares.

Reading takes fixed-size rows and rows whose lists all have one length (triangles) as numpy
records, and walks the others row by row; it returns None where a list length is negative or not
an integer, for ``plyfile``'s own reader. Writing packs rows with lists in the file's byte order.
"""
import itertools
import struct

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

_STRUCT_CODES = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I"}


# ---------------------------------------------------------------------------------------------
# Reading


def binary_element(element, fh, order, plyfile):
    """The rows of ``element`` from ``fh``, left after them; None where a list length is
    negative or not an integer (plyfile's reader then takes the file)."""
    count = element.count
    dtype = element.dtype(order)
    list_props = [p for p in element.properties if isinstance(p, plyfile.PlyListProperty)]
    if not list_props:
        data = np.empty(count, dtype)
        if dtype.itemsize:
            got = fh.readinto(data.view(np.uint8))
            if got < data.nbytes:
                raise plyfile.PlyElementParseError("early end-of-file", element,
                                                   got // dtype.itemsize)
        return data
    start = fh.tell()
    rows = _binary_lists(element, fh.read(), order, list_props, plyfile)
    if rows is None:
        return None
    data, end = rows
    fh.seek(start + end)
    return data


def _binary_lists(element, body, order, list_props, plyfile):
    """(rows, bytes they take) of an element with list properties at the start of ``body``;
    None where a list length is negative or not an integer."""
    count = element.count
    if any(np.dtype(p.len_dtype).kind not in "iu" for p in list_props):
        return None
    runs, fixed = [], 0  # per list: (bytes before it, its length's struct, value size)
    for prop in element.properties:
        if isinstance(prop, plyfile.PlyListProperty):
            runs.append((fixed, struct.Struct(order + _STRUCT_CODES[prop.len_dtype]),
                         np.dtype(prop.val_dtype).itemsize))
            fixed = 0
        else:
            fixed += np.dtype(prop.val_dtype).itemsize
    data = np.empty(count, element.dtype(order))
    if count == 0:
        return data, 0
    # Most elements hold lists of one length (triangles): every row is checked at once as a
    # record of the first row's layout, and rows are walked one by one from the first that
    # differs.
    first, at = [], 0
    for before, length, value in runs:
        at += before
        if at + length.size > len(body):
            raise plyfile.PlyElementParseError("early end-of-file", element, 0)
        first.append(length.unpack_from(body, at)[0])
        if first[-1] < 0:
            return None
        at += length.size + first[-1] * value
    if at + fixed > len(body):
        raise plyfile.PlyElementParseError("early end-of-file", element, 0)
    fields, lengths = [], iter(first)
    for prop in element.properties:
        if isinstance(prop, plyfile.PlyListProperty):
            fields += [(prop.name + "\nlen", order + prop.len_dtype),
                       (prop.name, order + prop.val_dtype, (next(lengths),))]
        else:
            fields.append((prop.name, order + prop.val_dtype))
    record = np.dtype(fields)
    fit = min(count, len(body) // record.itemsize)
    rows = np.frombuffer(body, record, fit)
    same = np.ones(fit, np.bool_)
    for prop, n in zip(list_props, first):
        same &= rows[prop.name + "\nlen"] == n
    uniform = fit if same.all() else int(np.argmin(same))
    if uniform == count:
        for prop in element.properties:
            values = rows[prop.name]
            if isinstance(prop, plyfile.PlyListProperty):
                values = lists(values.ravel(), np.full(count, values.shape[1]))
            data[prop.name] = values
        return data, count * record.itemsize
    walked = _walk_rows(element, body, runs, fixed, plyfile, uniform, uniform * record.itemsize)
    if walked is None:
        return None
    offsets = np.concatenate([np.arange(uniform) * record.itemsize, walked])
    text = np.frombuffer(body, np.uint8)
    cur = offsets[:-1].copy()
    for prop in element.properties:
        if isinstance(prop, plyfile.PlyListProperty):
            len_type = np.dtype(order + prop.len_dtype)
            lengths = _gather(text, cur, len_type).astype(np.int64)
            cur += len_type.itemsize
            val_type = np.dtype(order + prop.val_dtype)
            values = _gather(text, ragged(cur, lengths, val_type.itemsize), val_type)
            data[prop.name] = lists(values, lengths)
            cur += lengths * val_type.itemsize
        else:
            val_type = np.dtype(order + prop.val_dtype)
            data[prop.name] = _gather(text, cur, val_type)
            cur += val_type.itemsize
    return data, int(offsets[-1])


def _walk_rows(element, body, runs, tail, plyfile, row, at):
    """Where each row of a binary element with lists starts, from row ``row`` at byte ``at``
    of ``body`` on, and where the last one ends: an int64 array; None at a negative length.
    Raises plyfile's "early end-of-file" on the first row the body cannot hold."""
    offsets, size = [], len(body)
    if len(runs) == 1 and runs[0][1].format[-1] == "B":
        # One list of uchar length (faces, a range grid): bytes index as ints, fastest.
        before, _, value = runs[0]
        for k in range(row, element.count):
            offsets.append(at)
            at += before
            if at >= size:
                raise plyfile.PlyElementParseError("early end-of-file", element, k)
            at += 1 + body[at] * value + tail
            if at > size:
                raise plyfile.PlyElementParseError("early end-of-file", element, k)
    else:
        for k in range(row, element.count):
            offsets.append(at)
            for before, length, value in runs:
                at += before
                if at + length.size > size:
                    raise plyfile.PlyElementParseError("early end-of-file", element, k)
                n = length.unpack_from(body, at)[0]
                if n < 0:
                    return None
                at += length.size + n * value
            at += tail
            if at > size:
                raise plyfile.PlyElementParseError("early end-of-file", element, k)
    offsets.append(at)
    return np.array(offsets, np.int64)


def _gather(text, offsets, dtype):
    """The values of ``dtype`` at byte ``offsets`` of ``text``."""
    if len(offsets) == 0:
        return np.empty(0, dtype)
    return sliding_window_view(text, dtype.itemsize)[offsets].view(dtype)[:, 0]


# ---------------------------------------------------------------------------------------------
# Writing


def binary_rows(element, rows, order, plyfile):
    """The bytes of ``rows`` of an element with list properties."""
    columns, sizes = [], np.zeros(len(rows), np.int64)
    for prop in element.properties:
        if isinstance(prop, plyfile.PlyListProperty):
            lengths, values = list_column(prop, rows[prop.name], order)
            len_type = np.dtype(order + prop.len_dtype)
            columns.append((prop, lengths, values))
            sizes += len_type.itemsize + lengths * values.itemsize
        else:
            values = rows[prop.name].astype(order + prop.val_dtype)
            columns.append((prop, None, values))
            sizes += values.itemsize
    if len(rows) and all(lengths is None or (lengths == lengths[0]).all()
                         for _, lengths, _ in columns):
        # One layout for every row: a record array, as for triangles.
        fields = []
        for prop, lengths, values in columns:
            if lengths is None:
                fields.append((prop.name, values.dtype))
            else:
                fields += [(prop.name + "\nlen", order + prop.len_dtype),
                           (prop.name, values.dtype, (int(lengths[0]),))]
        out = np.empty(len(rows), fields)
        for prop, lengths, values in columns:
            if lengths is not None:
                out[prop.name + "\nlen"] = lengths
                values = values.reshape(len(rows), lengths[0])
            out[prop.name] = values
        return out.tobytes()
    out = np.empty(sizes.sum(), np.uint8)
    cur = np.cumsum(sizes) - sizes
    for prop, lengths, values in columns:
        if lengths is not None:
            len_type = np.dtype(order + prop.len_dtype)
            _scatter(out, cur, lengths.astype(len_type))
            cur += len_type.itemsize
            _scatter(out, ragged(cur, lengths, values.itemsize), values)
            cur += lengths * values.itemsize
        else:
            _scatter(out, cur, values)
            cur += values.itemsize
    return out.tobytes()


def _scatter(out, offsets, values):
    """Put the bytes of ``values`` at byte ``offsets`` of ``out``."""
    size = values.itemsize
    out[offsets[:, None] + np.arange(size)] = np.ascontiguousarray(values).view(
        np.uint8).reshape(-1, size)


# ---------------------------------------------------------------------------------------------
# List properties, in either body


def ragged(first, lengths, step=1):
    """``first[i] + step * j`` for ``j < lengths[i]``, row after row."""
    offsets = np.cumsum(lengths) - lengths
    return np.repeat(first - offsets * step, lengths) + np.arange(lengths.sum()) * step


def lists(values, lengths):
    """An object array of one array per row, as plyfile holds a list property: row ``i`` holds
    the next ``lengths[i]`` of ``values``."""
    out = np.empty(len(lengths), object)
    out.fill(values[:0])  # one empty array for every empty row
    offsets = np.cumsum(lengths) - lengths
    order = np.argsort(lengths, kind="stable")
    bounds = np.flatnonzero(np.diff(lengths[order], prepend=-1, append=-1))
    for at, end in itertools.pairwise(bounds):
        rows, length = order[at:end], int(lengths[order[at]])
        if length == 0:
            continue
        if len(rows) == len(lengths):
            block = values.reshape(len(rows), length)
        else:
            block = values[offsets[rows][:, None] + np.arange(length)]
        out[rows] = np.fromiter(block, object, len(rows))
    return out


def list_column(prop, column, order):
    """(lengths, values) of a list property's rows, each flattened and cast to its value type
    as plyfile writes it; the lengths must fit the length type."""
    dtype = np.dtype(order + prop.val_dtype)
    try:
        lengths = np.fromiter(map(len, column), np.int64, len(column))
        filled = column[lengths > 0]
        values = (np.concatenate(filled) if len(filled) else np.empty(0)).astype(dtype)
        whole = values.ndim == 1 and values.size == lengths.sum()
    except (TypeError, ValueError):  # scalars or nested rows
        whole = False
    if not whole:
        rows = [np.asarray(row, dtype).ravel() for row in column]
        lengths = np.array([row.size for row in rows], np.int64)
        values = np.concatenate(rows) if rows else np.empty(0, dtype)
    limit = np.iinfo(prop.len_dtype).max if np.dtype(prop.len_dtype).kind in "iu" else np.inf
    if len(lengths) and lengths.max() > limit:
        raise ValueError(f"list property {prop.name!r} has a row of {lengths.max():,} values; "
                         f"its length type {prop.len_dtype} counts at most {limit:,}")
    return lengths, values
