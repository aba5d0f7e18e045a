"""A cloud on disk, for tiled runs: the plan of :func:`pssd_fast.denoise` computed from chunks,
and the points binned into tile files (docs/ALGORITHM.md, "Tiled runs").

Each pass reads the input in chunks of :data:`CHUNK_POINTS`, so the memory it needs follows
the chunk and the tile sizes, not the cloud's. The passes:

1. bounds of the points (the centre and the Morton scale of ``denoise``);
2. a histogram of the top bits of the Morton code of each point's position
   (:func:`pssd_fast.duplicates.codes`), then the points binned into *buckets*, consecutive
   ranges of codes holding at most ``tile_points`` points each, and each bucket sorted: their
   concatenation is ``denoise``'s Morton order, so the noise probe reads its evenly spread
   sample (every ``s``-th point of that order) by rank; the rows at the position of an earlier
   row are set aside there, to take its result when the output is written
   (:mod:`pssd_fast.duplicates`);
3. per grid edge tried, the cells the points fall in, counted bucket by bucket;
4. the points binned again, into *tiles* of whole cells, in Morton order.
"""
import copy
import os
from pathlib import Path

import numpy as np

from .. import atomic, core, duplicates, regions
from .._validation import check_size
from ..graph import MORTON_BITS, bounds, cell_keys, cell_order

#: Points read from the input at a time.
CHUNK_POINTS = 1 << 20
#: The fields a LAS/LAZ output gets, by the names ``pssd denoise --fields`` gives them.
FIELDS = ("likelihood", "feature_intensity", "displacement")
#: What a LAS/LAZ output of a tiled run may hold besides the points.
RESULT_FIELDS = (*FIELDS, "normals")
#: Histogram bins of the Morton codes' top bits (7 per axis).
_PREFIX_BITS = 21
#: A point in a bucket or tile file: its row in the input, its Morton code, its coordinates.
RECORD = np.dtype([("row", np.int64), ("code", np.uint64), ("xyz", np.float64, 3)])
#: The same with the point's unit normal, for a file that has normals.
RECORD_NORMALS = np.dtype([*RECORD.descr, ("nrm", np.float64, 3)])
#: A row at the position of an earlier one: its row, the row it was merged into (its first),
#: its coordinates.
COPY = np.dtype([("row", np.int64), ("first", np.int64), ("xyz", np.float64, 3)])
#: What zarr and its codecs raise on a corrupt store is open-ended: ValueError (its own and
#: JSON's), OSError, KeyError, TypeError, ZeroDivisionError (a chunk shape of 0), and from the
#: codecs RuntimeError, SystemError (blosc), MemoryError (a chunk header claiming terabytes),
#: zlib.error... Zarr input is opened and read only through zarr, so all of them are caught there
#: and named in one line (docs/DECISIONS.md, "Readers that survive any file").
_ZARR_FAILURES = Exception


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

    def __getitem__(self, rows):
        return self.chunk(rows.start or 0, rows.stop)[0]

    def chunk(self, start, stop):
        """The coordinates of rows ``start..stop-1``, and their normals or None.

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
        return points, normals

    def classification(self):
        """Each point's class (the ``classification`` field, as :func:`pssd_fast.io.read`
        reads it), read in chunks."""
        found = np.empty(self.shape[0], np.uint8)
        for start in range(0, self.shape[0], CHUNK_POINTS):
            values = np.asarray(self._records(start, start + CHUNK_POINTS)["classification"])
            found[start:start + values.shape[0]] = values
        return found

    def _records(self, start, stop):
        """The records of rows ``start..stop-1`` (see :meth:`chunk`)."""
        from ..io.las import corrupt, failures, read_records

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
            raise ValueError(f"{self.path}: truncated; its header claims {self.shape[0]:,} "
                             f"points, but point {start + len(records):,} is missing")
        header = self.header
        return self.laspy.ScaleAwarePointRecord(records, header.point_format, header.scales,
                                                header.offsets)

    def close(self):
        """Close the reader :meth:`chunk` keeps open between calls, if any."""
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


def chunks(array, keep=None):
    """``(rows, points, normals)`` over ``array`` (n, 3) of real numbers, each chunk as
    float64 and checked for NaN and Inf; ``normals``: the file's, of unit length as
    :func:`pssd_fast.denoise` makes them, or None. ``keep(start, stop)``: a mask of the rows
    ``start..stop-1`` to take (every row where None); ``rows``: the rows taken."""
    for start, points, normals in _read(array):
        # Every point is checked, as denoise checks those of a classification's classes.
        points = _finite(np.ascontiguousarray(points, dtype=np.float64), start, "points")
        rows = np.arange(start, start + points.shape[0])
        if keep is not None:
            taken = keep(start, start + points.shape[0])
            if not taken.any():
                continue
            rows, points = rows[taken], points[taken]
            normals = None if normals is None else normals[taken]
        if normals is not None:
            normals = _finite(normals, start, "normals")
            length = np.linalg.norm(normals, axis=1)
            zero = ~(length > 0.0)
            if zero.any():
                raise ValueError(f"normals have {int(zero.sum())} zero-length row(s) from row "
                                 f"{start} on, the first is row "
                                 f"{start + int(np.flatnonzero(zero)[0])}")
            normals = normals / length[:, None]
        yield rows, points, normals


def _read(array):
    """``(start, points, normals)`` over ``array`` by chunks of :data:`CHUNK_POINTS` rows, as
    stored (normals: the file's, or None)."""
    for start in range(0, array.shape[0], CHUNK_POINTS):
        stop = start + CHUNK_POINTS
        points, normals = (array.chunk(start, stop) if hasattr(array, "chunk")
                           else (array[start:stop], None))
        yield start, points, normals


def unmoved(array, keep, path):
    """The rows of ``array`` that ``keep`` selects (as :func:`chunks` takes it) as
    :data:`PART` records in a new file at ``path``, as :func:`pssd_fast.denoise` returns
    the points of the classes it does not denoise: their coordinates and normals as read
    (NaN without), NaN likelihood and feature intensity, zero displacement."""
    with open(path, "wb") as out:
        for start, points, normals in _read(array):
            rows = np.flatnonzero(keep(start, start + points.shape[0]))
            normals = (np.full((rows.shape[0], 3), np.nan) if normals is None
                       else normals[rows])
            nan = np.full(rows.shape[0], np.nan)
            part_records(rows + start, points[rows], normals, nan, nan,
                         np.zeros(rows.shape[0])).tofile(out)


def _finite(values, start, name):
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        first = start + int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} contain NaN or Inf in {int(bad.sum())} row(s) from row "
                         f"{start} on; the first is row {first}; drop or repair those rows")
    return values


class Buckets:
    """The cloud's distinct positions in ``denoise``'s Morton order, relative to its centre, as
    files of consecutive ranks: ``shape`` and ``[::step]`` as a ``(n, 3)`` array offers them
    (what the noise probe reads), and :meth:`each` for the rest. The rows at the position of
    an earlier row (:mod:`pssd_fast.duplicates`; ``tolerance``: ``denoise``'s
    ``duplicate_tolerance``) are set aside in the :data:`COPY` file ``copies``,
    ``duplicates`` of them, out of ``rows`` rows in all: the rows of ``array`` that ``keep``
    selects (as :func:`chunks` takes it; every row where None), each keeping its row."""

    def __init__(self, array, folder, tile_points, tolerance=0.0, keep=None):
        n = 0
        low = np.full(3, np.inf)
        high = np.full(3, -np.inf)
        self.dtype = RECORD_NORMALS if getattr(array, "has_normals", False) else RECORD
        for _, points, _ in chunks(array, keep):
            n += points.shape[0]
            lo, hi = bounds(points)
            low, high = np.minimum(low, lo), np.maximum(high, hi)
        check_size(n)
        self.rows = n
        self.centre = 0.5 * (low + high)
        # The grid of the default method's cells starts at the low corner of every row, as in
        # core.
        self.corner = low - self.centre
        origin = low  # of the cubes of the tolerance
        shift = np.uint64(3 * MORTON_BITS - _PREFIX_BITS)
        histogram = np.zeros(1 << _PREFIX_BITS, np.int64)
        for _, points, _ in chunks(array, keep):
            prefix = (duplicates.codes(points, origin, high, tolerance) >> shift).astype(np.int64)
            histogram += np.bincount(prefix, minlength=1 << _PREFIX_BITS)
        bucket_of_bin = _bins(histogram, tile_points)
        self.folder = Path(folder)
        self.paths = [folder / f"bucket_{i}.bin" for i in range(int(bucket_of_bin.max()) + 1)]
        writers = [open(path, "wb") for path in self.paths]
        try:
            for rows, points, normals in chunks(array, keep):
                records = np.empty(points.shape[0], self.dtype)
                records["row"] = rows
                records["code"] = codes = duplicates.codes(points, origin, high, tolerance)
                records["xyz"] = points
                if normals is not None:
                    records["nrm"] = normals
                _append(writers, bucket_of_bin[codes >> shift], records)
        finally:
            for writer in writers:
                writer.close()
        counts = []
        # The rows at one position share its code (pssd_fast.duplicates), so a bucket holds
        # whole positions and merges its own; the bounds are then those of the distinct
        # positions, as in core.
        self.copies = folder / "copies.bin"
        low = np.full(3, np.inf)
        high = np.full(3, -np.inf)
        with open(self.copies, "wb") as out:
            for path in self.paths:
                records = np.fromfile(path, self.dtype)
                # Rows were appended in input order: a stable sort by code is denoise's order.
                records = records[np.argsort(records["code"], kind="stable")]
                into = duplicates.merged(records["code"], lambda at: duplicates.keys(
                    records["xyz"][at], origin, tolerance))
                if into is not None:
                    copy = into != np.arange(into.shape[0])
                    aside = np.empty(np.count_nonzero(copy), COPY)
                    aside["row"] = records["row"][copy]
                    aside["first"] = records["row"][into[copy]]
                    aside["xyz"] = records["xyz"][copy]
                    aside.tofile(out)
                    records = records[~copy]
                records.tofile(path)
                counts.append(records.shape[0])
                lo, hi = bounds(records["xyz"])
                low, high = np.minimum(low, lo), np.maximum(high, hi)
        self.starts = np.concatenate(([0], np.cumsum(counts)))
        self.shape = (int(self.starts[-1]), 3)
        self.duplicates = n - self.shape[0]
        # Bounds of the points relative to the centre: the same rounding, so the same bits.
        self.low, self.high = low - self.centre, high - self.centre

    def each(self):
        """The records of each bucket in turn (input row, Morton code, coordinates), in
        Morton order."""
        for path in self.paths:
            yield np.fromfile(path, self.dtype)

    def __getitem__(self, key):
        return self.ranked("xyz", key) - self.centre

    def ranked(self, field, key):
        """The ``field`` of every ``key.step``-th point of the Morton order (``key``: a slice
        ``[::step]``)."""
        if not isinstance(key, slice) or key.start is not None or key.stop is not None:
            raise TypeError("only [::step] is read from the buckets")
        ranks = np.arange(0, self.shape[0], key.step or 1)
        out = np.empty((ranks.shape[0], 3))
        for i, path in enumerate(self.paths):
            lo, hi = np.searchsorted(ranks, self.starts[i:i + 2])
            if hi > lo:
                records = np.fromfile(path, self.dtype)
                out[lo:hi] = records[field][ranks[lo:hi] - self.starts[i]]
        return out

    @property
    def normals(self):
        """The file's unit normals, ``[::step]`` as :meth:`__getitem__` reads points; or None."""
        if "nrm" not in self.dtype.names:
            return None
        buckets = self

        class Normals:
            shape = buckets.shape

            def __getitem__(self, key):
                return buckets.ranked("nrm", key)

        return Normals()

    def cells(self, plan, store, tile_points):
        """The points grouped by the cells of ``plan`` into ``store``, as
        :func:`pssd_fast.executor.group` puts them (each entry also with the points' input
        ``row``), out of core: each point's cell code, a histogram of the codes' first bits, and
        the points binned by those bits into tiles of whole cells of at most ``tile_points``
        points (a fuller bin alone), in the order of their cells. Returns the tiles
        (:class:`pssd_fast.executor.Tile`)."""
        from ..executor import Tile

        def keys_of(records, shift=None):
            return cell_keys(records["xyz"] - self.centre, plan.low, plan.edge, shift)

        # One shift for every bucket, from the whole cloud's largest cell coordinate: that of
        # its high corner, rounded as each point's is (graph.cell_keys).
        top = int(((self.high - plan.low) * (1.0 / plan.edge)).max())
        shift = max(0, top.bit_length() - MORTON_BITS)
        # The codes' first bits: as many as they use, less the prefix; a bucket's codes at a
        # time, so that memory follows the buckets.
        largest = max(int(keys_of(records, shift)[0].max(initial=0)) for records in self.each())
        prefix = np.uint64(max(0, largest.bit_length() - _PREFIX_BITS))
        histogram = np.zeros(1 << _PREFIX_BITS, np.int64)
        for records in self.each():
            histogram += np.bincount((keys_of(records, shift)[0] >> prefix).astype(np.int64),
                                     minlength=1 << _PREFIX_BITS)
        bucket_of_bin = _bins(histogram, tile_points)
        paths = [self.folder / f"cells_{i}.bin" for i in range(int(bucket_of_bin.max()) + 1)]
        cell_record = np.dtype([("gid", np.int64), ("code", np.uint64), *[
            (name, self.dtype[name]) for name in self.dtype.names if name != "code"]])
        writers = [open(path, "wb") for path in paths]
        try:
            for i, records in enumerate(self.each()):
                out = np.empty(records.shape[0], cell_record)
                out["gid"] = self.starts[i] + np.arange(records.shape[0])
                out["code"] = code = keys_of(records, shift)[0]
                for name in records.dtype.names:
                    if name != "code":
                        out[name] = records[name]
                _append(writers, bucket_of_bin[code >> prefix], out)
        finally:
            for writer in writers:
                writer.close()
        tiles = []
        c0 = 0
        for i, path in enumerate(paths):
            records = np.fromfile(path, cell_record)
            path.unlink()
            # Appended in the Morton order of the points: grouped stably by cell, the points
            # of a cell stay in that order, as in core.
            code, cells = keys_of(records, shift)
            order, starts = cell_order(code, cells)
            records = records[order]
            m = starts.shape[0] - 1
            xyz = records["xyz"] - self.centre
            normals = records["nrm"] if "nrm" in records.dtype.names else None
            means, mean_normals = core.cell_means(xyz, normals, np.arange(xyz.shape[0]),
                                                  starts)
            counts = np.diff(starts)
            points = {"xyz": xyz, "gid": records["gid"], "row": records["row"],
                      "cell": c0 + np.repeat(np.arange(m), counts)}
            cells = {"xyz": means, "mass": counts.astype(np.float64),
                     "gid": np.arange(c0, c0 + m)}
            if normals is not None:
                points["given"] = normals
                cells["normals"] = mean_normals
            store.put(("points", i), points)
            store.put(("cells", i, 0), cells)
            tiles.append(Tile(c0, m, xyz.shape[0], regions.boxes(xyz), regions.boxes(means)))
            c0 += m
        return tiles


def _bins(histogram, tile_points):
    """The bucket of each bin of ``histogram``: consecutive bins, at most ``tile_points`` a
    bucket (a fuller bin alone)."""
    bucket_of_bin = np.zeros(histogram.shape[0], np.int64)
    filled = 0
    bucket = 0
    for b in np.flatnonzero(histogram):
        if filled and filled + histogram[b] > tile_points:
            bucket += 1
            filled = 0
        bucket_of_bin[b] = bucket
        filled += histogram[b]
    return bucket_of_bin


def _append(writers, target, records):
    """Append each of ``records`` to the file of its ``target``, keeping their order."""
    order = np.argsort(target, kind="stable")
    target = target[order]
    records = records[order]
    edges = np.flatnonzero(np.concatenate(([True], target[1:] != target[:-1], [True])))
    for a, b in zip(edges[:-1], edges[1:]):
        records[a:b].tofile(writers[target[a]])


def write_rows(path, parts, n, dtype, columns=("xyz",), copies=()):
    """The records of the ``parts`` files (:data:`PART`, any order) into a new ``.npy`` file
    of ``(n, c)`` ``dtype``, in row order: the fields ``columns`` side by side; each row of
    the ``copies`` files (:data:`COPY`) takes the record of its first row, with the
    displacement from its own input position. Memory stays bounded: the records are first
    binned by blocks of :data:`CHUNK_POINTS` rows, then each block is written whole."""
    folder = Path(parts[0]).parent
    blocks = [folder / f"rows_{i}.bin" for i in range(-(-n // CHUNK_POINTS))]
    writers = [open(block, "wb") for block in blocks]
    try:
        for part in parts:
            records = np.fromfile(part, PART)
            _append(writers, records["row"] // CHUNK_POINTS, records)
    finally:
        for writer in writers:
            writer.close()
    if copies:
        _copy_records(blocks, copies)
    width = columns_width(columns)
    header = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=(n, width))
    offset = header.offset
    del header
    with open(path, "r+b") as fh:
        for i, block in enumerate(blocks):
            records = np.fromfile(block, PART)
            start = i * CHUNK_POINTS
            out = np.empty((min(n, start + CHUNK_POINTS) - start, width), dtype)
            out[records["row"] - start] = np.column_stack([records[c] for c in columns])
            fh.seek(offset + start * width * dtype.itemsize)
            out.tofile(fh)


def _copy_records(blocks, copies):
    """The record of each row of the ``copies`` files appended to the block of its row: its
    first row's record (found in that row's block), the displacement its own."""
    by_first = [block.with_name(f"{block.stem}_copies.bin") for block in blocks]
    writers = [open(path, "wb") for path in by_first]
    try:
        for found in copies:
            for start in range(0, os.path.getsize(found) // COPY.itemsize, CHUNK_POINTS):
                aside = np.fromfile(found, COPY, count=CHUNK_POINTS,
                                    offset=start * COPY.itemsize)
                _append(writers, aside["first"] // CHUNK_POINTS, aside)
    finally:
        for writer in writers:
            writer.close()
    writers = [open(block, "ab") for block in blocks]
    try:
        for i, (block, path) in enumerate(zip(blocks, by_first)):
            aside = np.fromfile(path, COPY)
            if not aside.shape[0]:
                continue
            writers[i].flush()  # copies appended here so far: whole records
            records = np.fromfile(block, PART)
            at = np.empty(CHUNK_POINTS, np.int64)
            at[records["row"] - i * CHUNK_POINTS] = np.arange(records.shape[0])
            found = records[at[aside["first"] - i * CHUNK_POINTS]]
            found["row"] = aside["row"]
            found["displacement"] = np.linalg.norm(found["xyz"] - aside["xyz"], axis=1)
            _append(writers, aside["row"] // CHUNK_POINTS, found)
    finally:
        for writer in writers:
            writer.close()


def columns_width(columns):
    """The columns the fields ``columns`` of :data:`PART` take side by side."""
    return sum(PART[c].shape[0] if PART[c].shape else 1 for c in columns)


def part_records(rows, points, normals, likelihood, feature, displacement):
    """The :data:`PART` records of denoised points (coordinates as the output holds them)."""
    records = np.empty(rows.shape[0], PART)
    records["row"] = rows
    records["xyz"] = points
    records["nrm"] = normals
    records["likelihood"] = likelihood
    records["feature"] = feature
    records["displacement"] = displacement
    return records


def save(records, path):
    """``records`` to ``path``, whole or not at all (:func:`pssd_fast.atomic.replacing`): a
    task run again while a worker thought lost still writes the same part leaves one whole
    part, never a mix."""
    with atomic.replacing(path) as fh:
        records.tofile(fh)


#: A denoised point: its input row, coordinates, normal, likelihood, feature intensity and
#: displacement (the columns of the result of ``denoise``, before its dtype).
PART = np.dtype([("row", np.int64), ("xyz", np.float64, 3), ("nrm", np.float64, 3),
                 ("likelihood", np.float64), ("feature", np.float64),
                 ("displacement", np.float64)])
#: The fields of :data:`PART` a LAS/LAZ output takes from it, in the order of its table.
TABLE = ("xyz", "nrm", "likelihood", "feature", "displacement")
