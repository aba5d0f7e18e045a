"""PLY files, ASCII or binary: every element, property and comment kept.

``plyfile`` holds the parsed file (``PlyData``, one ``PlyElement`` per element) and parses the
header; the bodies are read and written with numpy, a whole column at a time, with the values,
dtypes and bytes ``plyfile`` gives (:mod:`._ply_text` for ASCII bodies, :mod:`._ply_binary` for
binary ones). An ASCII body holding anything but plain numbers (or a row that does not parse) is
read by ``plyfile``'s own row-by-row reader instead, whose values and errors are the reference;
so is a binary list with a negative or non-integer length.
"""
import copy
import io
import re
import warnings
from dataclasses import dataclass

import numpy as np

from ._common import (COORDS, NORMALS, PointCloudFileError, PointCloudWarning, Source, fit_dtype,
                      need, stream_size)
from ._ply_binary import binary_element, binary_rows
from ._ply_text import Tokens, ascii_element, text_rows

# A PLY header is a few hundred bytes; a file without "end_header" in its first MiB is not PLY.
PLY_HEADER_LIMIT = 2**20
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4,
              "float32": 4, "double": 8, "float64": 8}
_PLY_END = re.compile(rb"(?:^|[\r\n])end_header[ \t]*(?:\r\n|\r|\n)")
# Types PLY can store, and where 64-bit or bool values go instead (if they fit exactly).
_PLY_KINDS = {"i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"}
_PLY_NARROW = {"b1": "u1", "i8": "i4", "u8": "u4"}
# Rows formatted or packed at once (ASCII, or binary with lists): bounds the working memory.
PLY_BLOCK = 2**16


@dataclass(frozen=True)
class _PlySource(Source):
    ply: object  # plyfile.PlyData with all elements in memory

    def take(self, rows):
        vertex = copy.copy(self.ply["vertex"])
        vertex.data = self.ply["vertex"].data[rows]
        # The other elements' vertex indices renumbered to the rows kept (-1: dropped).
        n = self.ply["vertex"].count
        renumber = np.full(n, -1, np.int64)
        renumber[np.arange(n)[rows]] = np.arange(vertex.data.shape[0])
        elements = [vertex] + [_renumbered(self.path, e, renumber) for e in self.ply.elements
                               if e.name != "vertex"]
        base = self.ply
        ply = type(base)(elements, text=base.text, byte_order=base.byte_order,
                         comments=base.comments, obj_info=base.obj_info)
        return _PlySource(ply, path=self.path)

    def coordinates_dtype(self):
        vertex = self.ply["vertex"].data
        float32 = "x" in vertex.dtype.names and vertex.dtype["x"] == np.float32
        return np.dtype(np.float32 if float32 else np.float64)


def _renumbered(path, element, renumber):
    """``element`` with its vertex index lists renumbered (``renumber``: each vertex's new
    index, -1 where dropped). A scanner's ``range_grid`` keeps its cells, those of dropped
    vertices emptied (a cell without a sample); any other element (faces, edges) loses the
    rows that index a dropped vertex, with a note."""
    names = [p.name for p in element.properties if p.name in ("vertex_indices", "vertex_index")
             and hasattr(p, "len_dtype")]
    if not names:
        return element
    data = element.data.copy()
    lists = [renumber[np.asarray(row, np.int64)] for row in data[names[0]]]
    if element.name == "range_grid":
        kept = np.ones(len(lists), np.bool_)
        lists = [row[row >= 0] for row in lists]
    else:
        kept = np.array([bool((row >= 0).all()) for row in lists], np.bool_)
        if not kept.all():
            warnings.warn(f"{path}: {int((~kept).sum()):,} of its {len(kept):,} "
                          f"{element.name} rows index dropped vertices and are dropped",
                          PointCloudWarning, stacklevel=4)
    column = np.empty(len(lists), object)
    column[:] = [row.astype(data[names[0]][i].dtype) for i, row in enumerate(lists)]
    data[names[0]] = column
    out = copy.copy(element)
    out.data = data[kept]
    return out


@dataclass(frozen=True)
class _PlyLayout:
    ascii: bool
    header_lines: int
    counts: dict  # element name -> row count, in file order
    body: int  # offset of the first byte after the header


def _ply_layout(path, fh, size):
    """Parse the header enough to check its element counts against the file size.

    Elements are allocated from their header counts before a row is read, so a header
    claiming a billion vertices must be refused here, from the bytes a row needs at least:
    its fixed size in binary files, two characters per value (digit and separator) in ASCII.
    """
    head = fh.read(PLY_HEADER_LIMIT)
    if not head.startswith(b"ply"):
        raise PointCloudFileError(f"{path}: not a PLY file (it does not start with 'ply')")
    end = _PLY_END.search(head)
    if end is None:
        raise PointCloudFileError(f"{path}: PLY header has no 'end_header' line (truncated or "
                                  f"not a PLY file)")
    lines = head[:end.end()].decode("ascii", "replace").splitlines()
    fmt, elements = None, []  # elements: [name, count, bytes per row at least]
    for lineno, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0] == "format" and len(tokens) > 1:
            fmt = tokens[1]
        elif tokens[0] == "element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise PointCloudFileError(f"{path}: bad PLY header line {lineno}: {line!r}")
            elements.append([tokens[1], int(tokens[2]), 0])
        elif tokens[0] == "property" and elements:
            # A list costs at least its length field (it may be empty): its first type.
            type_ = [*tokens, "", ""][2 if tokens[1:2] == ["list"] else 1]
            if type_ not in _PLY_SIZES:
                raise PointCloudFileError(f"{path}: unknown PLY type on header line {lineno}: "
                                          f"{line!r}")
            elements[-1][2] += 2 if fmt == "ascii" else _PLY_SIZES[type_]
    have = size - end.end()
    need = 0
    for name, count, row in elements:
        need += count * row
        # An ASCII file may lack the final newline.
        if need > have + (fmt == "ascii"):
            raise PointCloudFileError(
                f"{path}: header claims {count:,} '{name}' elements, which need at least "
                f"{need:,} bytes, but only {have:,} bytes follow the header (truncated file or "
                f"wrong header)")
    return _PlyLayout(fmt == "ascii", len(lines), {name: count for name, count, _ in elements},
                      end.end())


def _ply_parse_error(path, exc, layout, plyfile):
    """One-line message for a plyfile parse error, with the file line for ASCII data."""
    if isinstance(exc, plyfile.PlyHeaderParseError):
        return PointCloudFileError(f"{path}: bad PLY header (line {exc.line}): {exc.message}")
    name = exc.element.name if exc.element is not None else "?"
    if exc.message == "early end-of-file":
        return PointCloudFileError(f"{path}: truncated: element '{name}' ends after {exc.row:,} "
                                   f"of {layout.counts.get(name, 0):,} rows")
    where = f"row {exc.row} of element '{name}'"
    if layout.ascii and exc.row is not None:
        before = 0
        for other, count in layout.counts.items():
            if other == name:
                break
            before += count
        where = f"line {layout.header_lines + before + exc.row + 1} ('{name}' row {exc.row})"
    prop = f", property '{exc.prop.name}'" if exc.prop is not None else ""
    return PointCloudFileError(f"{path}: {exc.message} on {where}{prop}")


def read(path, fh, ext):
    """Read a PLY file, ASCII or binary.

    Parameters
    ----------
    path : pathlib.Path or str
        The file's name, for messages.
    fh : binary file object
        The data, seekable, at its start.
    ext : str
        ``".ply"``.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        The vertex ``x y z``, as float64.
    normals : (n, 3) numpy.ndarray or None
        The vertex ``nx ny nz`` as float64, or None if the vertices lack one of them.
    fields : dict of str to (n,) numpy.ndarray
        Every other scalar vertex property, in its type with native byte order.
    source : object
        The whole parsed file, for :func:`payload` to write back.

    Raises
    ------
    PointCloudFileError
        On a malformed or truncated file, a header claiming more rows than the file can hold
        (checked before anything is allocated), or no vertex ``x y z``.
    ImportError
        If ``plyfile`` is not installed.
    """
    plyfile = need("plyfile", "plyfile", "Reading .ply files")
    layout = _ply_layout(path, fh, stream_size(fh))
    fh.seek(0)
    try:
        ply = _read_columns(fh, layout, plyfile)
        if ply is None:
            fh.seek(0)
            ply = _read_rows(fh, layout, plyfile)
    except plyfile.PlyParseError as exc:
        raise _ply_parse_error(path, exc, layout, plyfile) from None
    except UnicodeDecodeError:
        raise PointCloudFileError(f"{path}: non-ASCII bytes in the PLY header or in its "
                                  f"ASCII data") from None
    except OverflowError as exc:  # an ASCII value beyond its integer type: 300 as uchar
        raise PointCloudFileError(f"{path}: a value does not fit the type of its PLY "
                                  f"property ({exc})") from None
    except ValueError as exc:  # plyfile's checks outside its parser: names given twice
        raise PointCloudFileError(f"{path}: bad PLY header: {exc}") from None
    if "vertex" not in ply:
        raise PointCloudFileError(f"{path}: has no 'vertex' element")
    vertex = ply["vertex"]
    scalar = [p.name for p in vertex.properties if not isinstance(p, plyfile.PlyListProperty)]
    missing = [c for c in COORDS if c not in scalar]
    if missing:
        raise PointCloudFileError(f"{path}: vertex element has no {', '.join(missing)} property")
    data = vertex.data
    points = np.column_stack([data[c] for c in COORDS]).astype(np.float64)
    normals = None
    if all(c in scalar for c in NORMALS):
        normals = np.column_stack([data[c] for c in NORMALS]).astype(np.float64)
    fields = {name: data[name].astype(data.dtype[name].newbyteorder("="))
              for name in scalar if name not in COORDS + NORMALS}
    return points, normals, fields, _PlySource(ply)


def _read_rows(fh, layout, plyfile):
    """The file read by plyfile's own reader, row by row."""
    # ASCII data goes through a text wrapper of ours, detached after the read: the one plyfile
    # would make closes ``fh`` when it is collected, with a ResourceWarning.
    stream = io.TextIOWrapper(fh, "ascii") if layout.ascii else fh
    try:
        with warnings.catch_warnings():
            # An empty list (a range grid's pixel without a return: a row "0") makes numpy
            # warn that it "contained no data"; it is read as the empty list it is.
            warnings.filterwarnings("ignore", "loadtxt: input contained no data",
                                    UserWarning)
            ply = plyfile.PlyData.read(stream)
    finally:
        if stream is not fh:
            stream.detach()
    for element in ply.elements:
        # plyfile memory-maps binary elements copy-on-write; untouched pages of such a map
        # follow later changes of the file, so the cloud takes its own copy.
        element.data = np.array(element.data)
    return ply


# ---------------------------------------------------------------------------------------------
# Reading the body a column at a time


def _read_columns(fh, layout, plyfile):
    """The file with every element read by numpy, or None where a row needs plyfile's reader.

    The header is plyfile's (``PlyData._parse_header``, what ``PlyData.read`` runs), read as
    :func:`_read_rows` has plyfile read it: through a text wrapper where the first header
    check saw an ASCII format line, byte by byte otherwise.
    """
    if layout.ascii:
        stream = io.TextIOWrapper(fh, "ascii")
        try:
            ply = plyfile.PlyData._parse_header(stream)
        finally:
            stream.detach()
        if not ply.text:
            return None  # plyfile refuses a binary body behind a text header
        fh.seek(layout.body)  # the wrapper read ahead
    else:
        ply = plyfile.PlyData._parse_header(fh)
    if not ply.text:
        for element in ply.elements:
            data = binary_element(element, fh, ply.byte_order, plyfile)
            if data is None:
                return None
            element.data = data
        return ply
    tokens = Tokens.split(np.frombuffer(fh.read(), np.uint8),
                           sum(e.count for e in ply.elements))
    if tokens is None:
        return None
    line = 0
    for element in ply.elements:
        data = ascii_element(element, tokens, line, plyfile)
        if data is None:
            return None
        element.data = data
        line += element.count
    return ply

# ---------------------------------------------------------------------------------------------
# The cloud's description and writing


def describe(source):
    """Lines naming what a PLY file holds beyond its vertices: other elements and counts."""
    other = [f"{e.name} ({e.count:,})" for e in source.ply.elements if e.name != "vertex"]
    return [f"other elements: {', '.join(other) if other else 'none'}"]


def _ply_values(name, values):
    """``values`` in a type PLY can store (64-bit and bool values narrowed if they fit)."""
    code = values.dtype.str[1:]
    if code in _PLY_KINDS:
        return values
    if code in _PLY_NARROW:
        return fit_dtype(name, values, _PLY_NARROW[code], "a PLY property")
    raise ValueError(f"field {name!r} has dtype {values.dtype}, which PLY cannot store")


def payload(path, ext, points, normals, fields, source):
    """Prepare a PLY file, keeping everything of ``source`` but the values given.

    Parameters
    ----------
    path : pathlib.Path or str
        The output's name, for messages.
    ext : str
        ``".ply"``.
    points : (n, 3) numpy.ndarray
        Coordinates, written in the type of the source's ``x`` (float64 for a new file).
    normals : (n, 3) numpy.ndarray or None
        Normals, written in the type of the source's ``nx ny nz`` or of the coordinates.
    fields : dict of str to (n,) numpy.ndarray
        Vertex properties; one the source has keeps its type and must fit it, a new one keeps
        its own (64-bit and bool values narrowed if they fit exactly).
    source : object or None
        What :func:`read` returned for a PLY input (its other elements, comments, ``obj_info``,
        ASCII/binary and byte order are kept), or None for a new little-endian binary file.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given (:func:`_write`).

    Raises
    ------
    PointCloudFileError
        If a value does not fit its property type, or a field is a list property of the source.
    ImportError
        If ``plyfile`` is not installed.
    """
    plyfile = need("plyfile", "plyfile", "Writing .ply files")
    columns, lists = {}, {}  # name -> (n,) values; name -> list property of the source
    comments = []
    if source is not None:
        vertex = source.ply["vertex"]
        comments = vertex.comments
        for prop in vertex.properties:
            columns[prop.name] = vertex.data[prop.name]
            if isinstance(prop, plyfile.PlyListProperty):
                lists[prop.name] = prop
    coord_type = columns["x"].dtype if "x" in columns else np.dtype(np.float64)
    try:
        for group, values in ((COORDS, points), (NORMALS, normals)):
            if values is not None:
                for i, name in enumerate(group):
                    stored = columns[name].dtype if name in columns else coord_type
                    columns[name] = fit_dtype(name, values[:, i], stored, "the PLY coordinates")
        for name, values in fields.items():
            if name in lists:
                raise ValueError(f"field {name!r} is a list property of the input PLY")
            if name in columns:
                if not np.array_equal(columns[name], values):
                    columns[name] = fit_dtype(name, values, columns[name].dtype, "its PLY property")
            else:
                columns[name] = _ply_values(name, values)
    except ValueError as exc:
        raise PointCloudFileError(f"{path}: {exc}") from None
    data = np.empty(len(points), dtype=[(name, col.dtype.newbyteorder("="))
                                        for name, col in columns.items()])
    for name, col in columns.items():
        data[name] = col
    element = plyfile.PlyElement.describe(
        data, "vertex", len_types={k: p.len_dtype for k, p in lists.items()},
        val_types={k: p.val_dtype for k, p in lists.items()},
        comments=comments)
    if source is None:
        ply = plyfile.PlyData([element], text=False, byte_order="<")
    else:
        base = source.ply
        ply = plyfile.PlyData([element if e.name == "vertex" else e for e in base.elements],
                              text=base.text, byte_order=base.byte_order,
                              comments=base.comments, obj_info=base.obj_info)
    return lambda fh: _write(ply, fh)


def _write(ply, fh):
    """Write ``ply`` (a ``plyfile.PlyData``) to the binary file ``fh``: the header and binary
    rows as ``PlyData.write`` writes them; ASCII rows with each float in the fewest digits
    that read back to its value (at most 9 for float32, 17 for float64)."""
    plyfile = need("plyfile", "plyfile", "Writing .ply files")
    fh.write(ply.header.encode("ascii") + b"\n")
    # NaN are written as they are; a signalling one would set numpy's "invalid" flag.
    with np.errstate(invalid="ignore"):
        for element in ply.elements:
            _write_element(element, ply, fh, plyfile)


def _write_element(element, ply, fh, plyfile):
    """Write the rows of ``element``, a block of rows at a time."""
    if not ply.text and not any(isinstance(p, plyfile.PlyListProperty)
                                for p in element.properties):
        if element.dtype().itemsize:
            fh.write(np.ascontiguousarray(
                element.data.astype(element.dtype(ply.byte_order), copy=False)).tobytes())
        return
    for at in range(0, element.count, PLY_BLOCK):
        rows = element.data[at:at + PLY_BLOCK]
        fh.write(text_rows(element, rows, plyfile) if ply.text
                 else binary_rows(element, rows, ply.byte_order, plyfile))
