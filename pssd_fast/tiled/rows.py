"""The output of a run from a file in the input's row order, written by rounds of tasks
(docs/tiled.md, "Out of core"): each task writes one block of rows (:class:`~ondisk.Blocks`)
into its place in the output, so no process holds more than a block and the calling process
only plans.

The tiles' results arrive as files of the output's columns of :data:`~ondisk.PART`
(:func:`ondisk.part_dtype`) sorted by block (:func:`ondisk.sorted_save`); the rows set aside
as copies of an earlier row (:data:`~ondisk.COPY`) take that row's record, found in its block
by a task of that block.
"""
import numpy as np

from . import ondisk


def write(runner, path, sources, blocks, n, dtype, columns=("xyz",), copies=(), stage=(0, 1)):
    """The records of the ``sources`` (``(path, counts)``: a file of records of ``columns``,
    :func:`~ondisk.part_dtype`, sorted by ``blocks``, :class:`~ondisk.Blocks`, and its count of
    each block) into a new ``.npy`` file at ``path`` of ``(n, c)`` ``dtype``, in row order:
    the fields ``columns`` side by side; each row of the ``copies`` files
    (:data:`~ondisk.COPY`) takes the record of its first row, with the displacement from its
    own input position. ``stage``: the iteration and iterations the tasks report. Returns the
    largest and the summed distance of the copies' rows from their input positions."""
    paths = [source for source, _ in sources]
    found = ondisk.offsets([counts for _, counts in sources])
    moved = (0.0, 0.0)
    if copies:
        by_first = [copy.with_name(copy.stem + "_by_first.bin") for copy in copies]
        first_found = ondisk.offsets(runner.map("copies", *stage, _by_first, [
            (copy, blocks, out) for copy, out in zip(copies, by_first)]))
        targets = [j for j in range(blocks.count) if any(c[j] for _, c in first_found)]
        copied = [copies[0].with_name(f"copied_{j}.bin") for j in targets]
        done = runner.map("copied", *stage, _copied, [
            (j, ondisk.pieces(paths, found, j), ondisk.pieces(by_first, first_found, j),
             blocks, columns, out) for j, out in zip(targets, copied)])
        paths += copied
        found += ondisk.offsets([counts for counts, _, _ in done])
        moved = (max((largest for _, largest, _ in done), default=0.0),
                 sum(total for _, _, total in done))
    width = ondisk.columns_width(columns)
    header = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=(n, width))
    offset = header.offset
    del header
    runner.map("write", *stage, _write_block, [
        (ondisk.pieces(paths, found, i), i, blocks, n, dtype, columns, path, offset)
        for i in range(blocks.count)])
    return moved


def _by_first(copies, blocks, out, n_jobs):
    """A :data:`~ondisk.COPY` file sorted by the block of each row's first row into ``out``;
    the count of each block."""
    aside = np.fromfile(copies, ondisk.COPY)
    return ondisk.sorted_save(aside, aside["first"] // blocks.size, blocks.count, out)


def _copied(j, records, aside, blocks, columns, out, n_jobs):
    """The record of each row set aside (``aside``: the pieces of the copies whose first row
    lies in block ``j``; ``records``: the pieces of block ``j``, of ``columns``): its first
    row's record, the displacement its own; sorted by the block of its own row into ``out``;
    the count of each block, and the largest and the summed displacement."""
    records = ondisk.read_pieces(records, ondisk.part_dtype(columns))
    aside = ondisk.read_pieces(aside, ondisk.COPY)
    at = np.empty(blocks.size, np.int64)
    at[records["row"] - j * blocks.size] = np.arange(records.shape[0])
    found = records[at[aside["first"] - j * blocks.size]]
    found["row"] = aside["row"]
    moved = np.linalg.norm(found["xyz"] - aside["xyz"], axis=1)
    if "displacement" in columns:
        found["displacement"] = moved
    return (ondisk.sorted_save(found, found["row"] // blocks.size, blocks.count, out),
            float(moved.max(initial=0.0)), float(moved.sum()))


def _write_block(pieces, i, blocks, n, dtype, columns, path, offset, n_jobs):
    """Block ``i`` of the output at ``path`` (its array from byte ``offset``) from the records
    of ``pieces``, every row of the block among them."""
    records = ondisk.read_pieces(pieces, ondisk.part_dtype(columns))
    start = i * blocks.size
    width = ondisk.columns_width(columns)
    out = np.empty((min(n, start + blocks.size) - start, width), dtype)
    out[records["row"] - start] = np.column_stack([records[c] for c in columns])
    with open(path, "r+b") as fh:
        fh.seek(offset + start * width * dtype.itemsize)
        out.tofile(fh)
