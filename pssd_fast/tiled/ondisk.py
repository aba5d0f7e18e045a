"""The files of tiled runs: the input read by chunks of rows (``.npy``, LAS/LAZ, Zarr), the
records the tasks write in the scratch folder, and the outputs of the input's kind
(docs/tiled.md, "Out of core"). Every task reads and writes its own files whole
(:func:`save`), so a task run again writes the same bytes again.
"""
import copy
import os
import threading
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import atomic

#: Points read from the input at a time.
CHUNK_POINTS = 1 << 20
#: The fields a LAS/LAZ output gets, by the names ``pssd denoise --fields`` gives them.
FIELDS = ("likelihood", "feature_intensity", "displacement")
#: What a LAS/LAZ output of a tiled run may hold besides the points.
RESULT_FIELDS = (*FIELDS, "normals")
#: A row at the position of an earlier one: its row, the row it was merged into (its first),
#: its coordinates.
COPY = np.dtype([("row", np.int64), ("first", np.int64), ("xyz", np.float64, 3)])
#: What zarr and its codecs raise on a corrupt store is open-ended: ValueError (its own and
#: JSON's), OSError, KeyError, TypeError, ZeroDivisionError (a chunk shape of 0), and from the
#: codecs RuntimeError, SystemError (blosc), MemoryError (a chunk header claiming terabytes),
#: zlib.error... Zarr input is opened and read only through zarr, so all of them are caught there
#: and named in one line (docs/DECISIONS.md, "Readers that survive any file").
_ZARR_FAILURES = Exception


class Blocks(NamedTuple):
    """Rows in blocks of ``size``, ``count`` of them: the chunks a pass reads and the blocks
    the output is written in. Tasks get them as arguments, never from this module, so that
    every process cuts the rows alike."""

    size: int
    count: int

    @classmethod
    def of(cls, n):
        """The blocks of :data:`CHUNK_POINTS` rows of ``n`` rows."""
        return cls(CHUNK_POINTS, -(-n // CHUNK_POINTS))

    def ranges(self):
        """``(start, stop)`` of each block."""
        return [(start, start + self.size) for start in range(0, self.size * self.count,
                                                              self.size)]


class NpyFile:
    """An ``.npy`` file of a real ``(n, columns)`` array, read by rows with plain reads (a
    memory map would keep every page read resident in the process)."""

    def __init__(self, path, columns=3):
        from ..io.npy import npy_header

        self.path = path
        with open(path, "rb") as fh:
            # Checked against the file's size: a truncated file is refused here.
            self.shape, fortran, self.dtype = npy_header(path, fh, os.fstat(fh.fileno()).st_size,
                                                         "the array")
            self.offset = fh.tell()
        if self.dtype.kind not in "fiu":
            raise TypeError(f"{path}: points must hold real numbers; got dtype {self.dtype}")
        if len(self.shape) != 2 or self.shape[1] != columns:
            raise ValueError(f"{path}: points must have shape (n, {columns}); got "
                             f"{self.shape}")
        if fortran:
            raise ValueError(f"{path}: a Fortran-ordered array; save it C-ordered")

    def __getitem__(self, rows):
        start, stop = rows.start or 0, min(rows.stop, self.shape[0])
        width = self.shape[1]
        with open(self.path, "rb") as fh:
            fh.seek(self.offset + start * width * self.dtype.itemsize)
            data = np.fromfile(fh, self.dtype, width * (stop - start))
        if data.shape[0] != width * (stop - start):
            raise ValueError(f"{self.path}: truncated; its header claims {self.shape[0]:,} "
                             f"rows, but row {start + data.shape[0] // width:,} is missing")
        return data.reshape(-1, width)


class LasFile:
    """A LAS or LAZ file's coordinates (the integers times the scale plus the offset, as
    :func:`pssd_fast.io.read` computes them) and its normals (``nx``, ``ny``, ``nz``, if it has
    them), read by rows through laspy."""

    def __init__(self, path):
        from ..io._common import NORMALS
        from ..io.las import _need_laspy, check_header, corrupt, failures

        self.path = path
        self.laspy = _need_laspy(Path(path).suffix.lower(), "Reading")
        with open(path, "rb") as fh:
            check_header(path, fh, os.fstat(fh.fileno()).st_size)
        try:
            with self.laspy.open(path) as reader:
                self.header = reader.header
        except failures(self.laspy) as exc:
            raise corrupt(path, exc) from None
        self.shape = (self.header.point_count, 3)
        self.dtype = np.dtype(np.float64)
        self.has_normals = set(NORMALS) <= set(self.header.point_format.dimension_names)
        self._cursor = None  # (reader, row it is at) between calls of chunk()
        # Tasks on threads share this object, and with it the reader: one reads at a time.
        self._lock = threading.Lock()

    def __getitem__(self, rows):
        return self.chunk(rows.start or 0, rows.stop)[0]

    def chunk(self, start, stop, classes=False):
        """The coordinates of rows ``start..stop-1``, and their normals or None; with
        ``classes``, their classes as a third item (:meth:`classification`), from the same
        read.

        Rows that follow the previous call's are read on from there, and a read from row 0
        opens the file afresh: laspy fills the rows beyond a LAZ file's real end with zeros
        after a seek, where a read from the start fails. Only other starts seek.
        """
        from ..io._common import NORMALS

        records = self._records(start, stop)
        header = self.header
        with np.errstate(invalid="ignore", over="ignore"):  # NaN and Inf are refused later
            points = np.column_stack([records.array[c] * s + o for c, s, o in
                                      zip("XYZ", header.scales, header.offsets, strict=True)])
        normals = None
        if self.has_normals:
            # As pssd_fast.io.read takes them.
            normals = np.column_stack([np.asarray(records[c]) for c in NORMALS]).astype(
                np.float64)
        if classes:
            return points, normals, np.asarray(records["classification"], np.uint8)
        return points, normals

    def __getstate__(self):
        # For a task in another process: laspy is imported again there, no reader is kept.
        return {**self.__dict__, "laspy": None, "_cursor": None, "_lock": None}

    def __setstate__(self, state):
        from ..io.las import _need_laspy

        self.__dict__.update(state)
        self.laspy = _need_laspy(Path(self.path).suffix.lower(), "Reading")
        self._lock = threading.Lock()

    def classification(self, start, stop):
        """The class of each of rows ``start..stop-1`` (the ``classification`` field, as
        :func:`pssd_fast.io.read` reads it)."""
        return np.asarray(self._records(start, stop)["classification"], np.uint8)

    def _records(self, start, stop):
        """The records of rows ``start..stop-1`` (see :meth:`chunk`), read by one thread at
        a time."""
        from ..io.las import corrupt, failures, read_records

        with self._lock:
            stop = min(stop, self.shape[0])
            try:
                if self._cursor is None or self._cursor[1] != start:
                    self.close()
                    self._cursor = (self.laspy.open(self.path), start)
                    if start:
                        self._cursor[0].seek(start)
                reader = self._cursor[0]
                records = read_records(reader, stop - start)
            except failures(self.laspy) as exc:
                self.close()
                raise corrupt(self.path, exc) from None
            self._cursor = (reader, stop)
            if stop == self.shape[0]:
                self.close()
            if len(records) != stop - start:
                raise ValueError(f"{self.path}: truncated; its header claims "
                                 f"{self.shape[0]:,} points, but point "
                                 f"{start + len(records):,} is missing")
            header = self.header
            return self.laspy.ScaleAwarePointRecord(records, header.point_format,
                                                    header.scales, header.offsets)

    def close(self):
        """Close the reader :meth:`chunk` keeps open between calls, if any (called with
        the lock held, or where no task reads)."""
        if self._cursor is not None:
            self._cursor[0].close()
            self._cursor = None

    def write(self, path, table, fields=()):
        """A copy of this file with the columns of ``table`` (an ``(n, 9)`` array-like read
        by row slices: :data:`TABLE`) in its records: the coordinates quantised into ``X``,
        ``Y``, ``Z``; the normals into ``nx``, ``ny``, ``nz`` where the file has them or
        ``fields`` names them; of ``fields``, the likelihood, feature intensity and
        displacement into dimensions of those names (float32 extra bytes where the file has
        none), as :func:`pssd_fast.io.write` stores them; every other byte of
        the records, the header, the VLRs and the EVLRs as read (the point count, the bounds
        and the extra-bytes VLR as laspy writes them)."""
        from ..io._common import NORMALS
        from ..io.las import _quantise, new_dims, put_values

        compress = Path(path).suffix.lower() == ".laz"
        backend = self.laspy.LazBackend.LazrsParallel if compress else None
        scalars = [name for name in FIELDS if name in fields]
        normals = NORMALS if "normals" in fields or self.has_normals else ()
        names = (*scalars, *normals)  # the order pssd denoise adds them in
        with self.laspy.open(self.path) as reader:
            header = copy.deepcopy(reader.header)
            existing = set(header.point_format.dimension_names)
            new = new_dims(self.laspy, path, existing,
                           {name: np.zeros(0, np.float32) for name in names})
            if new:
                header.add_extra_dims(new)
            with self.laspy.open(path, mode="w", header=header, do_compress=compress,
                                 laz_backend=backend) as writer:
                start = 0
                for chunk in reader.chunk_iterator(CHUNK_POINTS):
                    stop = start + len(chunk)
                    rows = table[start:stop]
                    records = self.laspy.ScaleAwarePointRecord.zeros(len(chunk), header=header)
                    for name in chunk.array.dtype.names:
                        records.array[name] = chunk.array[name]
                    records.X, records.Y, records.Z = _quantise(
                        path, rows[:, :3], self.header.scales, self.header.offsets).T
                    # The result's columns as pssd denoise hands them to the writer.
                    put_values(path, records, existing, {
                        **dict(zip(normals, rows[:, 3:6].T)),
                        **{name: rows[:, 6 + FIELDS.index(name)].astype(np.float32)
                           for name in scalars}})
                    writer.write_points(records)
                    start = stop
                if reader.evlrs:
                    writer.write_evlrs(reader.evlrs)


class ZarrFile:
    """A Zarr array of a real ``(n, 3)`` array, or a Zarr group holding one as ``points``,
    read by rows (``pip install "pssd_fast[zarr]"``)."""

    def __init__(self, path):
        try:
            import zarr
        except ImportError as err:
            raise ImportError("Zarr input needs zarr: pip install 'pssd_fast[zarr]'") from err
        self.path = path
        try:
            found = zarr.open(str(path), mode="r")
            if not hasattr(found, "shape") and "points" in found:
                found = found["points"]
        except _ZARR_FAILURES as exc:
            raise ValueError(f"{path}: not a readable Zarr array or group "
                             f"({_named(exc)})") from None
        if not hasattr(found, "shape"):
            raise ValueError(f"{path}: a Zarr group without a 'points' array")
        self.array = found
        self.shape, self.dtype = found.shape, np.dtype(found.dtype)
        if self.dtype.kind not in "fiu":
            raise TypeError(f"{path}: points must hold real numbers; got dtype {self.dtype}")
        if len(self.shape) != 2 or self.shape[1] != 3:
            raise ValueError(f"{path}: points must have shape (n, 3); got {self.shape}")

    def __getitem__(self, rows):
        try:
            return np.asarray(self.array[rows])
        except _ZARR_FAILURES as exc:
            raise ValueError(f"{self.path}: cannot read rows {rows.start or 0:,} to "
                             f"{rows.stop:,} of the Zarr array (corrupt chunk?): "
                             f"{_named(exc)}") from None

    def write(self, path, points):
        """A new Zarr array at ``path`` of ``points`` (an ``(n, 3)`` array-like read by row
        slices), with this one's chunks and the result's dtype."""
        import zarr

        out = zarr.open_array(str(path), mode="w", shape=points.shape, dtype=points.dtype,
                              chunks=self.array.chunks)
        step = max(CHUNK_POINTS // self.array.chunks[0], 1) * self.array.chunks[0]
        for start in range(0, points.shape[0], step):
            out[start:start + step] = points[start:start + step]


def _named(exc):
    """``Type: message`` of an exception, on one line."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())


class Classes(NamedTuple):
    """The rows of a LAS/LAZ chunk whose class is one of ``codes`` (``invert``: none of
    them), found by the task that reads the chunk, from the same read: the calling process
    never holds a file's classes, nor ships a mask of its rows to the tasks."""

    codes: tuple
    invert: bool = False


def chunk(array, start, stop, mask=None):
    """``(rows, points, normals)`` of rows ``start..stop-1`` of ``array`` (n, 3) of real
    numbers, the points as float64 and checked for NaN and Inf; ``normals``: the file's, of
    unit length as :func:`pssd_fast.denoise` makes them, or None. ``mask``: the rows of the
    chunk to take (a boolean array or :class:`Classes`; every row where None); ``rows``: the
    rows taken."""
    points, normals, mask = _read(array, start, stop, mask)
    # Every point is checked, as denoise checks those of a classification's classes.
    points = _finite(np.ascontiguousarray(points, dtype=np.float64), start, "points")
    rows = np.arange(start, start + points.shape[0])
    if mask is not None:
        rows, points = rows[mask], points[mask]
        normals = None if normals is None else normals[mask]
    if normals is not None and points.shape[0]:
        normals = _finite(normals, start, "normals")
        length = np.linalg.norm(normals, axis=1)
        zero = ~(length > 0.0)
        if zero.any():
            raise ValueError(f"normals have {int(zero.sum())} zero-length row(s) from row "
                             f"{start} on, the first is row "
                             f"{start + int(np.flatnonzero(zero)[0])}")
        normals = normals / length[:, None]
    return rows, points, normals


def _read(array, start, stop, mask=None):
    """The points of rows ``start..stop-1`` as stored, the file's normals or None, and the
    rows ``mask`` selects as a boolean array (None: every row)."""
    if isinstance(mask, Classes):
        points, normals, classes = array.chunk(start, stop, classes=True)
        return points, normals, np.isin(classes, mask.codes) != mask.invert
    if hasattr(array, "chunk"):
        return (*array.chunk(start, stop), mask)
    return array[start:stop], None, mask


def unmoved(array, start, stop, mask, path, blocks, columns, n_jobs):
    """The rows ``start..stop-1`` of ``array`` that ``mask`` selects as records of the output's
    ``columns`` (:func:`part_dtype`) in a new file at ``path`` (a task), as
    :func:`pssd_fast.denoise` returns the points of the classes it does not denoise: their
    coordinates and normals as read (NaN without), NaN likelihood and feature intensity, zero
    displacement; the count of each of the output's :class:`Blocks` (:func:`sorted_save`)."""
    points, normals, mask = _read(array, start, stop, mask)
    rows = np.flatnonzero(mask)
    normals = np.full((rows.shape[0], 3), np.nan) if normals is None else normals[rows]
    nan = np.full(rows.shape[0], np.nan)
    records = part_records(part_dtype(columns), rows + start, xyz=points[rows], nrm=normals,
                           likelihood=nan, feature=nan, displacement=np.zeros(rows.shape[0]))
    return sorted_save(records, records["row"] // blocks.size, blocks.count, path)


def _finite(values, start, name):
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        first = start + int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} contain NaN or Inf in {int(bad.sum())} row(s) from row "
                         f"{start} on; the first is row {first}; drop or repair those rows")
    return values


def first_error(results):
    """``results``, or the first of them that is an exception, raised: the first bad chunk is
    named whatever order the tasks ran in."""
    for found in results:
        if isinstance(found, Exception):
            raise found
    return results


def take(records, order):
    """``records[order]`` (``order`` an index array), each record copied whole: numpy indexes a
    structured array field by field, 3 to 5 times slower."""
    whole = np.dtype((np.void, records.dtype.itemsize))
    return np.take(np.ascontiguousarray(records).view(whole), order).view(records.dtype)


def sorted_save(records, target, targets, path):
    """``records`` sorted stably by ``target`` (each below ``targets``) into a file at
    ``path``, whole (:func:`save`); the count of each of ``targets``."""
    # Records already in order (one bucket, one tile, a tile within one block) are saved as
    # they are: the gather of a sort would copy them all.
    if (target[1:] < target[:-1]).any():
        # numpy sorts keys of 16 bits stably by radix, in linear time: the same order.
        keys = target.astype(np.uint16) if targets <= 1 << 16 else target
        records = take(records, np.argsort(keys, kind="stable"))
    save(records, path)
    return np.bincount(target, minlength=targets)


def offsets(counts):
    """``(first, count)`` of each target in each file :func:`sorted_save` wrote, from the
    counts it returned."""
    return [(np.cumsum(c) - c, c) for c in counts]


def pieces(paths, found, b):
    """Where target ``b``'s records lie in the files ``paths`` (``found``: :func:`offsets`):
    ``(path, first record, records)`` of each file that holds some."""
    return [(path, int(first[b]), int(c[b])) for path, (first, c) in zip(paths, found)
            if c[b]]


def read_pieces(found, dtype):
    """The records of the :func:`pieces` ``found``, one after another (read into their place:
    no copy joins them)."""
    out = np.empty(sum(count for _, _, count in found), dtype)
    at = 0
    for path, first, count in found:
        with open(path, "rb") as fh:
            fh.seek(first * dtype.itemsize)
            into = memoryview(out[at:at + count].view(np.uint8))
            if fh.readinto(into) != into.nbytes:
                raise OSError(f"{path}: the file ends before its {first + count}-th record")
        at += count
    return out


def columns_width(columns):
    """The columns the fields ``columns`` of :data:`PART` take side by side."""
    return sum(PART[c].shape[0] if PART[c].shape else 1 for c in columns)


def part_dtype(columns):
    """The records of :data:`PART` with its ``row`` and the fields ``columns`` alone: what an
    output of those columns reads of the results."""
    return np.dtype([("row", np.int64)] + [(c, PART[c]) for c in columns])


def part_records(dtype, rows, **fields):
    """Records ``dtype`` (:func:`part_dtype`) of denoised points (coordinates as the output
    holds them): their ``rows`` and those of ``fields`` (``xyz``, ``nrm``, ``likelihood``,
    ``feature``, ``displacement``) it holds."""
    records = np.empty(rows.shape[0], dtype)
    records["row"] = rows
    for name in dtype.names[1:]:
        records[name] = fields[name]
    return records


def save(records, path):
    """``records`` to ``path``, whole or not at all (:func:`pssd_fast.atomic.scratch`): a
    task run again while a worker thought lost still writes the same part leaves one whole
    part, never a mix."""
    with atomic.scratch(path) as fh:
        records.tofile(fh)


#: A denoised point: its input row, coordinates, normal, likelihood, feature intensity and
#: displacement (the columns of the result of ``denoise``, before its dtype).
PART = np.dtype([("row", np.int64), ("xyz", np.float64, 3), ("nrm", np.float64, 3),
                 ("likelihood", np.float64), ("feature", np.float64),
                 ("displacement", np.float64)])
#: The fields of :data:`PART` a LAS/LAZ output takes from it, in the order of its table.
TABLE = ("xyz", "nrm", "likelihood", "feature", "displacement")
