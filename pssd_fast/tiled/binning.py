"""A cloud on disk binned into buckets and tiles by rounds of tasks (docs/tiled.md, "Out of
core"): the plan of :func:`pssd_fast.denoise` computed from chunks, and the points grouped
into the tiles' entries of the run's store.

Every pass is a round of tasks on the run's scheduler, one task a chunk of the input, a bucket
or a tile; the calling process plans the rounds and sums what the tasks return (counts,
bounds, sparse histograms), so its time and memory follow the number of chunks and tiles, not
of points. A task that runs again (a worker lost) writes the same files whole again. The
passes:

1. per chunk, its rows checked and their bounds (the centre and the Morton scale of
   ``denoise``);
2. per chunk, a sparse histogram of the top bits of the Morton code of each point's position
   (:func:`pssd_fast.duplicates.codes`); the driver groups consecutive bins into *buckets* of
   at most ``tile_points`` points, a fuller bin split by another pass of histograms of its
   codes' next bits (:func:`pssd_fast.regions.parts`: a far row leaves every other point in
   one bin of the first bits);
3. per chunk, its records sorted by bucket into a file of its own;
4. per bucket, its pieces of every chunk in input order, sorted by code: their concatenation
   is ``denoise``'s Morton order, so the noise probe reads its evenly spread sample (every
   ``s``-th point of that order) by rank, a task a bucket; the rows at the position of an
   earlier row are set aside, to take its result when the output is written
   (:mod:`pssd_fast.duplicates`);
5. per bucket, a sparse histogram of the first bits of the plan's cell codes (as many bits as
   the high corner's code has, less :data:`~pssd_fast.regions.PREFIX_BITS`); the driver
   groups them into *tiles* of whole cells, as in core (:func:`pssd_fast.executor.group`), a
   fuller bin split as in 2;
6. per bucket, its records sorted by tile; per tile, its pieces grouped by cell (which numbers
   its cells), then its store entries written with the cells numbered from the tiles before.
"""
from pathlib import Path

import numpy as np

from .. import core, duplicates, noise, regions
from .._validation import check_range, check_size
from ..graph import (MORTON_BITS, bounds, candidates, cell_keys, cell_order, code_order,
                     inside_boxes, merge_candidates)
from ..progress import BEFORE
from ..store import load
from . import ondisk

#: The shift that leaves a position code's top :data:`~pssd_fast.regions.PREFIX_BITS` bits (7
#: per axis).
_CODE_SHIFT = np.uint64(3 * MORTON_BITS - regions.PREFIX_BITS)
#: The probe's sample is read from a bucket file in runs: ranks closer than this many bytes
#: in one read (about what a read's own cost would read), within one window of ``SAMPLE_RUN``
#: records.
SAMPLE_GAP = 1 << 15
SAMPLE_RUN = 1 << 16
#: A point in a bucket file: its row in the input, its Morton code, its coordinates.
RECORD = np.dtype([("row", np.int64), ("code", np.uint64), ("xyz", np.float64, 3)])
#: The same with the point's unit normal, for a file that has normals.
RECORD_NORMALS = np.dtype([*RECORD.descr, ("nrm", np.float64, 3)])


class Buckets:
    """The cloud's distinct positions in ``denoise``'s Morton order, relative to its centre, as
    files of consecutive ranks: ``shape`` and ``[::step]`` as a ``(n, 3)`` array offers them
    (what the noise probe reads), and :meth:`cells` for the tiles. The rows at the position of
    an earlier row (:mod:`pssd_fast.duplicates`; ``tolerance``: ``denoise``'s
    ``duplicate_tolerance``) are set aside in the :data:`~pssd_fast.tiled.ondisk.COPY` files
    ``copies``, ``duplicates`` of them, out of ``rows`` rows in all: the rows of ``array`` that
    ``keep`` selects (``keep(start, stop)``: a mask of rows ``start..stop-1``, or the
    :class:`~pssd_fast.tiled.ondisk.Classes` that finds it; every row where None), each keeping
    its row. ``runner``: where the tasks run
    (:class:`pssd_fast.tiled.scheduler.Runner`)."""

    def __init__(self, array, folder, tile_points, tolerance, keep, runner):
        self.folder = folder = Path(folder)
        self.runner = runner
        self.dtype = RECORD_NORMALS if getattr(array, "has_normals", False) else RECORD
        chunks = [(array, start, stop, None if keep is None else keep(start, stop))
                  for start, stop in ondisk.Blocks.of(array.shape[0]).ranges()]
        found = [scan for scan in ondisk.first_error(runner.map("read", *BEFORE, _scan, chunks))
                 if scan[0]]
        n = sum(scan[0] for scan in found)
        check_size(n)
        self.rows = n
        low = np.min([scan[1] for scan in found], axis=0)
        high = np.max([scan[2] for scan in found], axis=0)
        check_range(low, high)
        self.centre = 0.5 * (low + high)
        # The grid of the default method's cells starts at the low corner of every row, as in
        # core.
        self.corner = low - self.centre
        codes = (low, high, tolerance)  # of the cubes of the tolerance
        firsts = regions.parts(
            regions.histogram(runner.map("histogram", *BEFORE, _code_prefixes,
                                         [(*chunk, codes) for chunk in chunks])),
            int(_CODE_SHIFT), tile_points,
            lambda split: runner.map("finer histogram", *BEFORE, _code_bins,
                                     [(*chunk, codes, split) for chunk in chunks]))
        pieces = [folder / f"chunk_{i}.bin" for i in range(len(chunks))]
        counts = ondisk.offsets(runner.map("bin", *BEFORE, _bin_chunk, [
            (*chunk, codes, firsts, self.dtype, path) for chunk, path in zip(chunks, pieces)]))
        self.paths = [folder / f"bucket_{b}.bin" for b in range(firsts.shape[0])]
        merged = runner.map("merge", *BEFORE, _merge_bucket, [
            (ondisk.pieces(pieces, counts, b), self.dtype, codes, path) for b, path in
            enumerate(self.paths)])
        for path in pieces:
            path.unlink()
        # Each bucket's box, for the buckets a query must read (sampled_variances).
        self.boxes = [(m[1] - self.centre, m[2] - self.centre) for m in merged]
        # The rows at one position share its code (pssd_fast.duplicates), so a bucket holds
        # whole positions and merges its own; the bounds are then those of the distinct
        # positions, as in core.
        self.copies = [path.with_name(path.stem + "_copies.bin") for path, m in
                       zip(self.paths, merged) if m[3]]
        self.starts = np.concatenate(([0], np.cumsum([m[0] for m in merged])))
        self.shape = (int(self.starts[-1]), 3)
        self.duplicates = n - self.shape[0]
        # Bounds of the points relative to the centre: the same rounding, so the same bits.
        self.low = np.min([m[1] for m in merged], axis=0) - self.centre
        self.high = np.max([m[2] for m in merged], axis=0) - self.centre

    def __getitem__(self, key):
        return self.ranked("xyz", key) - self.centre

    def ranked(self, field, key):
        """The ``field`` of every ``key.step``-th point of the Morton order (``key``: a slice
        ``[::step]``), read by a task a bucket (:func:`_sample`)."""
        if not isinstance(key, slice) or key.start is not None or key.stop is not None:
            raise TypeError("only [::step] is read from the buckets")
        ranks = np.arange(0, self.shape[0], key.step or 1)
        cuts = np.searchsorted(ranks, self.starts)
        parts = self.runner.map("sample", *BEFORE, _sample, [
            (path, self.dtype, field, ranks[cuts[i]:cuts[i + 1]] - self.starts[i])
            for i, path in enumerate(self.paths)])
        return np.concatenate(parts).reshape(-1, 3)

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

    def sampled_variances(self, sample, k, bound):
        """:func:`pssd_fast.noise.sampled_variances` of ``sample`` (points of the cloud, in
        its Morton order) by tasks: per bucket within ``bound`` of some of them, their
        :func:`~pssd_fast.graph.candidates` among its points, into a file; per block of
        :data:`~pssd_fast.noise.OWN_BLOCK` of them, their candidates from every bucket merged
        into the whole cloud's lists (:func:`~pssd_fast.graph.merge_candidates`) and read
        (:func:`pssd_fast.noise.own_variances`): the in-core values, bit for bit."""
        blocks = -(-sample.shape[0] // noise.OWN_BLOCK)
        # Every bucket that may hold a point within the bound: its box grown by a little more
        # than it (a bucket too many adds candidates beyond the lists, never changes them).
        reach = bound * (1.0 + 1e-9)
        argsets, pieces = [], []
        for b, (path, (low, high)) in enumerate(zip(self.paths, self.boxes)):
            at = np.flatnonzero(inside_boxes(sample, np.array([[low - reach, high + reach]])))
            if at.shape[0]:
                pieces.append(self.folder / f"own_{b}.bin")
                argsets.append((path, self.dtype, self.centre, int(self.starts[b]),
                                self.shape[0], sample[at], at, k, bound, blocks, pieces[-1]))
        counts = ondisk.offsets(self.runner.map("own lists", *BEFORE, _own_candidates,
                                                argsets))
        parts = self.runner.map("own fits", *BEFORE, _own_block, [
            (ondisk.pieces(pieces, counts, b), _own_record(k + 1), k, self.shape[0])
            for b in range(blocks)])
        for path in pieces:
            path.unlink()
        return np.concatenate(parts) if parts else np.empty(0)

    def cells(self, plan, store, tile_points):
        """The points grouped by the cells of ``plan`` into ``store``, as
        :func:`pssd_fast.executor.group` puts them (each entry also with the points' input
        ``row``), by tasks: each point's cell code, a histogram of the codes' first bits, and
        the points binned by those bits into tiles of whole cells of at most ``tile_points``
        points (a fuller bin split by its codes' next bits), in the order of their cells.
        Returns the tiles (:class:`pssd_fast.executor.Tile`)."""
        runner = self.runner
        # One shift for every bucket, from the whole cloud's high corner, as in core.
        shift, prefix = regions.code_shifts(self.high, plan.low, plan.edge)
        grid = (self.centre, plan.low, plan.edge, shift)
        buckets = [(path, self.dtype, grid) for path in self.paths]
        firsts = regions.parts(
            regions.histogram(runner.map("cell histogram", *BEFORE, _cell_prefixes,
                                         [(*bucket, prefix) for bucket in buckets])),
            prefix, tile_points,
            lambda split: runner.map("finer cell histogram", *BEFORE, _cell_bins,
                                     [(*bucket, split) for bucket in buckets]))
        pieces = [self.folder / f"cells_of_{i}.bin" for i in range(len(buckets))]
        counts = ondisk.offsets(runner.map("cell bin", *BEFORE, _bin_cells, [
            (*bucket, firsts, int(self.starts[i]), path)
            for i, (bucket, path) in enumerate(zip(buckets, pieces))]))
        record = _cell_record(self.dtype)
        grouped = [self.folder / f"cells_{t}.bin" for t in range(firsts.shape[0])]
        sizes = runner.map("cells", *BEFORE, _group_tile, [
            (ondisk.pieces(pieces, counts, t), record, grid, path)
            for t, path in enumerate(grouped)])
        for path in pieces:
            path.unlink()
        c0 = np.concatenate(([0], np.cumsum(sizes)))
        tiles = runner.map("tiles", *BEFORE, _put_tile, [
            (path, record, self.centre, int(c0[t]), store, t) for t, path in enumerate(grouped)])
        for path in self.paths:  # every point is in the tiles' entries now
            path.unlink()
        return tiles


def _scan(array, start, stop, mask, n_jobs):
    """The rows a chunk takes and their bounds; or the ValueError its rows raise, so that the
    first bad chunk is named whatever order the tasks ran in."""
    try:
        _, points, _ = ondisk.chunk(array, start, stop, mask)
    except ValueError as exc:
        return exc
    if not points.shape[0]:
        return 0, None, None
    return (points.shape[0], *bounds(points))


def _sample(path, dtype, field, ranks, n_jobs):
    """The ``field`` of the records at ``ranks`` (increasing) of a bucket file. Ranks closer
    than :data:`SAMPLE_GAP` bytes are read together, a run within one window of
    :data:`SAMPLE_RUN` records a read; farther ones alone: a memory map would keep the pages
    around each resident (95 MB of a bucket of 8,000,000 points for a sample every 5,200)."""
    out = np.empty((ranks.shape[0], 3))
    if not ranks.shape[0]:
        return out
    size = dtype.itemsize
    # A run starts at a rank far from the one before, or in another window of SAMPLE_RUN.
    cut = (np.diff(ranks) * size > SAMPLE_GAP) | (np.diff(ranks // SAMPLE_RUN) != 0)
    starts = np.concatenate(([0], np.flatnonzero(cut) + 1, [ranks.shape[0]])).tolist()
    with open(path, "rb") as fh:
        for a, b in zip(starts[:-1], starts[1:]):
            first = int(ranks[a])
            fh.seek(first * size)
            run = np.fromfile(fh, dtype, count=int(ranks[b - 1]) - first + 1)
            out[a:b] = run[field][ranks[a:b] - first]
    return out


def _own_record(q):
    """A sample point's candidates from one bucket: its place in the sample (``at``), and the
    distance, rank and position of each of its ``q`` nearest there."""
    return np.dtype([("at", np.int64), ("d", np.float64, q), ("rank", np.int64, q),
                     ("xyz", np.float64, (q, 3))])


def _own_candidates(path, dtype, centre, first, n, queries, at, k, bound, blocks, out,
                    n_jobs):
    """The :func:`~pssd_fast.graph.candidates` among a bucket's points (its first at rank
    ``first`` of ``n``) of the sample points ``queries`` (at ``at`` in the sample), as
    :func:`_own_record` records sorted by block of the sample into a file at ``out``; the
    count of each block."""
    xyz = np.fromfile(path, dtype)["xyz"] - centre
    m = xyz.shape[0]
    found = np.empty(queries.shape[0], _own_record(k + 1))
    found["at"] = at
    for start, stop, distances, rows in candidates(xyz, queries, k + 1, bound,
                                                   noise.OWN_BLOCK):
        found["d"][start:stop] = distances
        found["rank"][start:stop] = np.where(rows < m, rows + first, n)
        found["xyz"][start:stop] = xyz[np.minimum(rows, m - 1)]
    return ondisk.sorted_save(found, at // noise.OWN_BLOCK, blocks, out)


def _own_block(pieces, record, k, n, n_jobs):
    """:func:`pssd_fast.noise.own_variances` of a block of the sample, from its candidates in
    every bucket's file (``pieces``)."""
    records = ondisk.read_pieces(pieces, record)
    records = ondisk.take(records, np.argsort(records["at"], kind="stable"))
    at = records["at"]
    # Each sample point's candidates from its buckets side by side, in the buckets' order.
    first = np.flatnonzero(np.concatenate(([True], at[1:] != at[:-1])))
    sizes = np.diff(np.append(first, at.shape[0]))
    slot = np.arange(at.shape[0]) - np.repeat(first, sizes)
    row = np.repeat(np.arange(first.shape[0]), sizes)
    q = record["d"].shape[0]
    width = (int(slot.max()) + 1) * q
    distances = np.full((first.shape[0], width), np.inf)
    ranks = np.full((first.shape[0], width), n, np.int64)
    xyz = np.zeros((first.shape[0], width, 3))
    columns = slot[:, None] * q + np.arange(q)
    distances[row[:, None], columns] = records["d"]
    ranks[row[:, None], columns] = records["rank"]
    xyz[row[:, None], columns] = records["xyz"]
    _, lengths, order = merge_candidates(distances, ranks, k, n)
    return noise.own_variances(np.take_along_axis(xyz, order[:, :, None], axis=1), lengths)


def _code_prefixes(array, start, stop, mask, codes, n_jobs):
    """The sparse histogram (bins, counts) of the top bits of a chunk's position codes."""
    _, points, _ = ondisk.chunk(array, start, stop, mask)
    return np.unique(duplicates.codes(points, *codes) >> _CODE_SHIFT, return_counts=True)


def _code_bins(array, start, stop, mask, codes, split, n_jobs):
    """The sparse histogram of a chunk's position codes in the ranges ``split``
    (:func:`pssd_fast.regions.binned`)."""
    _, points, _ = ondisk.chunk(array, start, stop, mask)
    return regions.binned(duplicates.codes(points, *codes), split)


def _bin_chunk(array, start, stop, mask, codes, firsts, dtype, path, n_jobs):
    """A chunk's records (:data:`RECORD`) sorted by bucket (stably: in input order within
    one) into a file at ``path``; the count of each bucket."""
    rows, points, normals = ondisk.chunk(array, start, stop, mask)
    records = np.empty(points.shape[0], dtype)
    records["row"] = rows
    records["code"] = code = duplicates.codes(points, *codes)
    records["xyz"] = points
    if normals is not None:
        records["nrm"] = normals
    return ondisk.sorted_save(records, regions.part_of(firsts, code),
                              firsts.shape[0], path)


def _merge_bucket(pieces, dtype, codes, path, n_jobs):
    """A bucket's records from its ``pieces`` (in input order) sorted by code, with the rows at
    the position of an earlier row set aside in a copies file beside ``path``; its number of
    records, their bounds and the number set aside."""
    records = ondisk.read_pieces(pieces, dtype)
    # In input order: a stable sort by code is denoise's order.
    records = ondisk.take(records, code_order(records["code"]))
    low, _, tolerance = codes
    into = duplicates.merged(records["code"], lambda at: duplicates.keys(
        records["xyz"][at], low, tolerance))
    aside = 0
    if into is not None:
        copy = into != np.arange(into.shape[0])
        aside = int(np.count_nonzero(copy))
        copies = np.empty(aside, ondisk.COPY)
        copies["row"] = records["row"][copy]
        copies["first"] = records["row"][into[copy]]
        copies["xyz"] = records["xyz"][copy]
        if aside:
            ondisk.save(copies, path.with_name(path.stem + "_copies.bin"))
        records = records[~copy]
    ondisk.save(records, path)
    return (records.shape[0], *bounds(records["xyz"]), aside)


def _keys(records, grid):
    """The cell keys (:func:`pssd_fast.graph.cell_keys`) of bucket or tile records."""
    centre, low, edge, shift = grid
    return cell_keys(records["xyz"] - centre, low, edge, shift)


def _cell_prefixes(path, dtype, grid, prefix, n_jobs):
    """The sparse histogram (bins, counts) of the first bits of a bucket's cell codes."""
    return np.unique(_keys(np.fromfile(path, dtype), grid)[0] >> np.uint64(prefix),
                     return_counts=True)


def _cell_bins(path, dtype, grid, split, n_jobs):
    """The sparse histogram of a bucket's cell codes in the ranges ``split``
    (:func:`pssd_fast.regions.binned`)."""
    return regions.binned(_keys(np.fromfile(path, dtype), grid)[0], split)


def _cell_record(dtype):
    """A point on its way to a tile: its rank in the Morton order (``gid``), its cell code
    and the rest of its bucket record."""
    return np.dtype([("gid", np.int64), ("code", np.uint64), *[
        (name, dtype[name]) for name in dtype.names if name != "code"]])


def _bin_cells(path, dtype, grid, firsts, first_rank, out, n_jobs):
    """A bucket's points as :func:`_cell_record` records sorted by tile into a file at
    ``out``; the count of each tile."""
    records = np.fromfile(path, dtype)
    found = np.empty(records.shape[0], _cell_record(dtype))
    found["gid"] = first_rank + np.arange(records.shape[0])
    found["code"] = code = _keys(records, grid)[0]
    for name in records.dtype.names:
        if name != "code":
            found[name] = records[name]
    return ondisk.sorted_save(found, regions.part_of(firsts, code),
                              firsts.shape[0], out)


def _group_tile(pieces, record, grid, path, n_jobs):
    """A tile's points from its ``pieces`` (in Morton order) grouped by cell into a file at
    ``path``; its number of cells."""
    records = ondisk.read_pieces(pieces, record)
    # Grouped stably by cell, the points of a cell stay in the Morton order, as in core.
    code, cells = _keys(records, grid)
    order, starts = cell_order(code, cells)
    np.save(path.with_suffix(".starts.npy"), starts)
    ondisk.save(ondisk.take(records, order), path)
    return starts.shape[0] - 1


def _put_tile(path, record, centre, c0, store, i, n_jobs):
    """The store entries of tile ``i`` (its cells numbered from ``c0``), as
    :func:`pssd_fast.executor.group` puts them; the tile."""
    from ..executor import Tile

    records = np.fromfile(path, record)
    starts = load(path.with_suffix(".starts.npy"))
    m = starts.shape[0] - 1
    xyz = records["xyz"] - centre
    normals = records["nrm"] if "nrm" in records.dtype.names else None
    means, mean_normals = core.cell_means(xyz, normals, np.arange(xyz.shape[0]), starts)
    counts = np.diff(starts)
    points = {"xyz": xyz, "gid": records["gid"], "row": records["row"],
              "cell": c0 + np.repeat(np.arange(m), counts)}
    cells = {"xyz": means, "mass": counts.astype(np.float64), "gid": np.arange(c0, c0 + m)}
    if normals is not None:
        points["given"] = normals
        cells["normals"] = mean_normals
    store.put(("points", i), points)
    store.put(("cells", i, 0), cells)
    path.unlink()
    path.with_suffix(".starts.npy").unlink()
    return Tile(c0, m, xyz.shape[0], regions.boxes(xyz), regions.boxes(means))

