"""Tiled runs on Dask, with the in-core result (docs/tiled.md; docs/ALGORITHM.md, "Tiles").

The default method's steps run as rounds of tile tasks (:mod:`pssd_fast.executor`, the one
executor of :func:`pssd_fast.denoise` too): :func:`denoise` tiles an array in memory,
:func:`denoise_file` a file on disk, whose points never all sit in one process. Both take
:func:`pssd_fast.denoise`'s parameters and give its result, bit for bit.

Dask is an optional dependency: ``pip install ".[dask]"`` in the repository.
"""
import dataclasses
import inspect
import shutil
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import atomic, executor
from .. import classes as lidar
from ..denoise import checked_options
from ..denoise import run as run_in_core
from .. import plan as planning
from .._threads import threads
from .._validation import check_int, check_orient_estimated, check_precision
from ..parameters import BY_NAME, PARAMETERS
from ..progress import BEFORE, Clock, reporter
from ..run import Request, check_distinct, stats
from ..stats import finished
from ..store import Files, Memory
from . import binning, ondisk, rows
from .scheduler import LOCAL_SCHEDULERS, Runner, check_client

#: What :func:`denoise_file` reads and writes, by extension.
FILE_KINDS = {".npy": "npy", ".zarr": "zarr", ".las": "las", ".laz": "las"}
# Below this a tile's halo (every mean within a list bound of its own) holds several times
# its own points, and the rounds' tasks cost more than their work: on the CAD part at 20,000
# points, tiles of 500 take 4 times the in-core run, tiles of 50 about 65 times.
MIN_TILE_POINTS = 500


def _declared(func):
    """``func`` (which takes ``**options``) with a signature that names every parameter of
    :mod:`pssd_fast.parameters` at its default in their place, for ``help()`` and editors."""
    own = inspect.signature(func)
    kept = [p for p in own.parameters.values() if p.kind != inspect.Parameter.VAR_KEYWORD]
    func.__signature__ = own.replace(parameters=kept + [
        inspect.Parameter(p.name, inspect.Parameter.KEYWORD_ONLY, default=p.default)
        for p in PARAMETERS])
    return func


@_declared
def denoise(points, normals=None, *, tile_points=2_000_000, client=None, **options):
    """Denoise ``points`` tile by tile on Dask; the result of :func:`pssd_fast.denoise`.

    Parameters
    ----------
    points, normals
        As in :func:`pssd_fast.denoise`.
    tile_points : int
        The most points a tile holds, at least ``MIN_TILE_POINTS`` (500; a tile is never
        smaller than one cell of the default method). Tiles bound the memory of a task; the
        smaller they are, the more of each task is its halo (its neighbours' points).
    client : None, str or distributed.Client
        Where the tile tasks run: None or ``"threads"`` (Dask's local threads; the tiles'
        arrays stay in this process), ``"processes"`` or ``"sync"`` (Dask's local process
        pool, or this thread), a ``distributed.Client``, or the address of a Dask scheduler;
        tasks in other processes share the tiles' arrays through files in a scratch folder.
    **options
        :func:`pssd_fast.denoise`'s keyword arguments, all of them. ``n_jobs`` is the threads
        of this machine that the tasks share: the local schedulers run at most that many tasks
        at once, with ``n_jobs // tasks`` threads each (``"sync"``: one task with all of
        them); on ``distributed`` each worker shares its own cores between the tasks it runs
        at once. ``progress`` also hears of each finished tile of each round (stages
        ``tile_lists``, ``tile_fit``, ``tile_project``, ``tile_test``, ``tile_refine_fit``
        and others, docs/tiled.md).

    Returns
    -------
    DenoiseResult
        Bit-identical to ``pssd_fast.denoise(points, normals, **options)`` (the normals'
        signs under ``orient`` aside: tiles turn each normal on its own, where one tile
        propagates); ``stats["tiles"]`` gives the number of tiles, their most points, the
        scheduler and the ``threads`` the tasks took. The paper's pipeline and the baselines
        run in one task.

    Raises
    ------
    TypeError, ValueError
        As :func:`pssd_fast.denoise` raises them, and for a bad ``tile_points`` or
        ``client``.
    ImportError
        Without Dask.

    Warns
    -----
    DenoiseWarning
        As :func:`pssd_fast.denoise` warns (where classes chosen by default are too small to
        denoise: each class chosen runs tiled on its own, the other points kept as they are).

    Examples
    --------
    Tiles of at most 1,000 points, run in this thread, give the in-memory result bit for bit:

    >>> import numpy as np
    >>> import pssd_fast
    >>> from pssd_fast import datasets, tiled
    >>> points = datasets.make("cube", n_points=2000, seed=0).points
    >>> result = tiled.denoise(points, tile_points=1000, client="sync")
    >>> result.stats["tiles"]["count"], result.stats["tiles"]["most_points"]
    (2, 1000)
    >>> in_memory = pssd_fast.denoise(points)
    >>> np.array_equal(result.points, in_memory.points)
    True
    """
    tile_points = check_tile_points(tile_points)
    check_client(client)
    _check_options(options)
    with threads(options.get("n_jobs")) as n_threads, \
            Runner(client, n_threads, reporter(options.get("progress"))) as runner:
        if runner.name in ("threads", "sync"):
            return run_in_core(points, normals, options, runner, tile_points, Memory())
        folder = tempfile.mkdtemp(prefix="pssd_tiles_")
        try:
            return run_in_core(points, normals, options, runner, tile_points, Files(folder))
        finally:
            shutil.rmtree(folder, ignore_errors=True)


def check_tile_points(value):
    """``value`` checked as ``tile_points``: an int of at least ``MIN_TILE_POINTS``."""
    value = check_int(value, "tile_points")
    if value < MIN_TILE_POINTS:
        raise ValueError(f"tile_points must be at least {MIN_TILE_POINTS:,}; got {value:,} "
                         f"(a smaller tile is mostly the halo it reads from its neighbours)")
    return value


def _check_options(options):
    """TypeError naming the keywords that no declaration of :mod:`pssd_fast.parameters` names
    (which method takes a method parameter :func:`pssd_fast.denoise` checks itself)."""
    unknown = sorted(set(options) - set(BY_NAME))
    if unknown:
        raise TypeError(f"unknown parameter(s) {', '.join(unknown)}; tiled runs take "
                        f"pssd_fast.denoise's")


@_declared
def denoise_file(source, destination, *, tile_points=2_000_000, client=None, fields=(),
                 scratch=None, overwrite=False, **options):
    """Denoise the points of an ``.npy``, Zarr or LAS/LAZ file into another, out of core, tile
    by tile on Dask.

    The input is read in chunks and binned into tile files in a scratch folder; each task reads
    its tile and, of the others, the rows within its halo, and writes its results there; the
    output is written in the input's row order. Memory follows ``tile_points``, not the number
    of points. The result is that of :func:`pssd_fast.denoise`, bit for bit.

    Parameters
    ----------
    source : path-like
        An ``.npy`` file of a real ``(n, 3)`` array, a Zarr array of that shape (or a Zarr
        group holding one as ``points``; ``pip install "pssd_fast[zarr]"``), or a LAS/LAZ file
        (its ``nx``, ``ny``, ``nz`` are its normals where it has them; its ``classification``
        field gives each point's class, see ``**options``).
    destination : path-like
        Of the kind of ``source``, written only when complete: the denoised ``(n, 3)`` points
        in the input's rows (``.npy``, or a Zarr array of the input's chunks), float32 for
        float32 input and float64 otherwise; or a ``.las``/``.laz`` file: the input with the
        denoised coordinates (quantised as :func:`pssd_fast.io.write` quantises them), its own
        normals updated, the ``fields`` asked for (as ``pssd denoise --fields`` writes them),
        every other record byte, the header, the VLRs and the EVLRs as read.
    tile_points, client
        As in :func:`denoise`; the tasks read and write the scratch folder.
    fields : sequence of str
        LAS/LAZ output: which of ``"likelihood"``, ``"feature_intensity"``,
        ``"displacement"`` and ``"normals"`` to add (default none).
    scratch : path-like, optional
        Where the scratch folder goes (default: beside ``destination``); with a cluster, a
        folder every worker reads and writes. It is removed on success, on failure and on
        interrupt.
    overwrite : bool
        Replace an existing ``destination``.
    **options
        :func:`pssd_fast.denoise`'s keyword arguments, for the default method (presets
        "default" and "fast"). The paper's pipeline and the baselines and ``remove_outliers``
        need every point at once: :func:`pssd_fast.io.read`, then :func:`pssd_fast.denoise`
        or :func:`denoise`, runs them. ``classification``: of an ``.npy`` or Zarr input, as
        in :func:`pssd_fast.denoise`; a LAS/LAZ input's classes are its ``classification``
        field (counted first, by a task a chunk; each task then takes its class's rows of
        the chunk it reads), and it refuses ``classification``.
        ``classes``: as in :func:`pssd_fast.denoise`, of either; each class chosen runs out
        of core on its own (a run reads the file three times and takes the rows of its
        class), and the rows of the other classes keep their coordinates (a LAS/LAZ record
        byte for byte), their normals as read, NaN likelihood and feature intensity and zero
        displacement, as ``pssd denoise`` writes them in memory.

    Returns
    -------
    Stats
        The run's :class:`pssd_fast.Stats`, as :func:`pssd_fast.denoise` gives them (with
        classes, ``stats["classes"]`` says what ran; ``stats.to_dict()`` for JSON).

    Raises
    ------
    ValueError
        Bad input, unknown fields, other formats, the options above that need every point,
        too few distinct positions, or ``classification`` and ``classes`` as
        :func:`pssd_fast.denoise` refuses them (``classification`` with a LAS/LAZ file).
    FileExistsError
        ``destination`` exists and ``overwrite`` is False: checked first, and again by the
        final rename, which never replaces what another writer put there meanwhile.

    Warns
    -----
    DenoiseWarning
        Where classes chosen by default are too small to denoise, a class named is of no
        point, or float32 coordinates lie so far from the origin that their step exceeds 1%
        of the spacing, as :func:`pssd_fast.denoise` warns.

    Examples
    --------
    A float32 ``.npy`` file in, its denoised rows out, of the same shape and dtype:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from pssd_fast import datasets, tiled
    >>> points = datasets.make("cube", n_points=2000, seed=0).points.astype(np.float32)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     scan, clean = Path(folder, "scan.npy"), Path(folder, "clean.npy")
    ...     np.save(scan, points)
    ...     stats = tiled.denoise_file(scan, clean, tile_points=1000, client="sync")
    ...     denoised = np.load(clean)
    >>> denoised.shape, denoised.dtype
    ((2000, 3), dtype('float32'))
    >>> stats["n_points"], stats["tiles"]["count"], stats["plan"]["method"]
    (2000, 2, 'default')
    """
    source, destination = Path(source), Path(destination)
    kinds = {path: FILE_KINDS.get(path.suffix.lower()) for path in (source, destination)}
    if None in kinds.values() or len(set(kinds.values())) > 1:
        raise ValueError(f"denoise_file reads .npy into .npy, Zarr into Zarr, or .las/.laz "
                         f"into .las/.laz; got {source.name} and {destination.name} (other "
                         f"formats: pssd_fast.io.read, then denoise)")
    tile_points = check_tile_points(tile_points)
    check_client(client)
    _check_options(options)
    if kinds[source] == "las" and options.get("classification") is not None:
        raise ValueError(f"the classes of {source.name} are its classification field; pass "
                         f"classes=... alone")
    settings = _file_settings(options, kinds[source] == "las")
    unknown = sorted(set(fields) - set(ondisk.RESULT_FIELDS))
    if unknown:
        raise ValueError(f"unknown field(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(ondisk.RESULT_FIELDS)}")
    exists = f"{destination} exists; pass overwrite=True to replace it"
    if destination.exists() and not overwrite:
        raise FileExistsError(exists)
    if destination.resolve() == source.resolve():
        raise ValueError(f"the output {destination} would overwrite the input")
    atomic.check_folder(destination)
    array = {"npy": ondisk.NpyFile, "las": ondisk.LasFile, "zarr": ondisk.ZarrFile}[
        kinds[source]](source)
    dtype = np.dtype(np.float32) if array.dtype == np.float32 else np.dtype(np.float64)
    report = reporter(options.get("progress"))
    started = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix="pssd_tiles_", dir=scratch or destination.parent))
    # Beside the destination, so that the last rename stays on one file system.
    output = atomic.temporary(destination)
    try:
        with threads(options.get("n_jobs")) as n_threads, \
                Runner(client, n_threads, report) as runner:
            classified = _file_classes(array, options.get("classification"),
                                       options.get("classes"), runner)
            runs, small, least = [None], [], None
            if classified is not None:
                codes, counts, rows_of = classified
                least = lidar.least_points(options)
                found, small = lidar.choose(codes, counts, options.get("classes"), least)
                if found is None:
                    classified = None  # classes 0 and 1 only: no classification
                else:
                    runs = found
            setting = _FileRun(array, dtype, tile_points, settings, report, runner, n_threads,
                               ondisk.Blocks.of(array.shape[0]))
            done = []
            for code in runs:
                with lidar.naming(code), lidar.too_few(
                        code, None if code is None else int(counts[codes == code][0]),
                        options.get("classes"), small):
                    done.append((code, _file_run(setting, None, folder, started)
                                 if code is None else
                                 _file_run(setting, lambda a, b, code=code:
                                           rows_of(a, b, (code,), False),
                                           folder / f"class_{code}", time.perf_counter())))
            lidar.warn_small(small, least)
            lidar.check_some(done, least)
            last = done[-1][1].stats
            stage = (last["n_iterations"] - 1, last["n_iterations"])
            sources = [source for _, run in done for source in run.parts]
            if classified is not None:
                ranges = setting.blocks.ranges()
                kept = [folder / f"kept_{start}.bin" for start, _ in ranges]
                denoised = tuple(code for code, _ in done)  # not those left as too few
                sources += zip(kept, runner.map("kept", *stage, ondisk.unmoved, [
                    (array, start, stop, rows_of(start, stop, denoised, True), path,
                     setting.blocks, _columns(array))
                    for (start, stop), path in zip(ranges, kept)]))
            clock = Clock(report, *stage)
            copied = clock.run("write", _write, runner, array, output, sources, setting.blocks,
                               dtype, folder, fields,
                               [path for _, run in done for path in run.copies], stage)
            atomic.sync(output)
            atomic.replace(output, destination, overwrite=overwrite, exists_message=exists)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        if output.is_dir():
            shutil.rmtree(output, ignore_errors=True)
        output.unlink(missing_ok=True)
    if classified is None:
        found = done[0][1].stats
    else:
        found = lidar.summary(
            [(code, run.stats["n_points"], run.stats) for code, run in done],
            int(array.shape[0] - sum(run.stats["n_points"] for _, run in done)), small, runs,
            started)
    moved = [run.moved for _, run in done] + [copied]
    # Every row of the output, those of no class and those it left in place (zero) included.
    displacement = {"max": max(largest for largest, _ in moved),
                    "mean": sum(total for _, total in moved) / max(array.shape[0], 1)}
    return dataclasses.replace(finished(found, clock.times, started),
                               displacement=displacement)


class _Done(NamedTuple):
    """A run of :func:`_file_run`: its results (``(path, counts)`` of each tile's file of
    :func:`_part`), the files of rows set aside as copies, its ``stats`` and the largest and
    the summed distance of its rows from their input positions (``moved``)."""
    parts: list
    copies: list
    stats: object
    moved: tuple


class _FileRun(NamedTuple):
    """What each run of :func:`denoise_file` takes: the input ``array``, the output's
    ``dtype``, the call's settings, checked, where its tasks run and the output's blocks of
    rows."""
    array: object
    dtype: object
    tile_points: int
    settings: dict
    report: object
    runner: object
    n_threads: int
    blocks: ondisk.Blocks


def _file_classes(array, classification, classes, runner):
    """The classes of ``array``'s rows: the codes present (increasing), how many rows each
    has, and ``rows_of(start, stop, codes, invert)``, the rows of ``start..stop-1`` whose
    class is one of ``codes`` (``invert``: none of them), as a task's mask takes them; None
    for one cloud (``classes`` ``"all"``, or no classes). A LAS/LAZ file's are its
    classification field, counted by a task a chunk, and each task finds its own chunk's rows
    when it reads them (:class:`pssd_fast.tiled.ondisk.Classes`); else ``classification``,
    checked."""
    if isinstance(classes, str) and classes == "all":
        return None
    if isinstance(array, ondisk.LasFile):
        total = sum(runner.map("classes", *BEFORE, _class_counts, [
            (array, *rows) for rows in ondisk.Blocks.of(array.shape[0]).ranges()]),
            np.zeros(256, np.int64))
        present = np.flatnonzero(total)
        return (present.astype(np.uint8), total[present],
                lambda start, stop, codes, invert: ondisk.Classes(codes, invert))
    if classification is None:
        return None
    labels = lidar.check_labels(classification, array.shape[0])
    codes, counts = np.unique(labels, return_counts=True)
    return (codes, counts,
            lambda start, stop, codes, invert: np.isin(labels[start:stop], codes) != invert)


def _class_counts(array, start, stop, n_jobs):
    """How many of rows ``start..stop-1`` of a LAS/LAZ file are of each class 0-255 (a
    task)."""
    return np.bincount(array.classification(start, stop), minlength=256)


def _file_run(setting, keep, folder, started):
    """One run of :func:`denoise_file` on the rows of ``setting.array`` that ``keep`` selects
    (``keep(start, stop)``: a mask of rows ``start..stop-1`` or the
    :class:`~pssd_fast.tiled.ondisk.Classes` that finds it; None: every row), its scratch
    files in ``folder``: a :class:`_Done`."""
    folder.mkdir(exist_ok=True)
    settings, report, runner = setting.settings, setting.report, setting.runner
    first = Clock(report, *BEFORE)
    cloud = first.run("buckets", binning.Buckets, setting.array, folder, setting.tile_points,
                      settings["duplicate_tolerance"], keep, runner)
    n = check_distinct(cloud.shape[0], cloud.rows, None)
    # As denoise warns of a float32 array: the spacing from a sample of the buckets.
    check_precision(cloud, setting.dtype, float(np.abs(
        np.stack([cloud.low, cloud.high]) + cloud.centre).max()))
    check_orient_estimated(settings["orient"], cloud.normals is not None,
                           f"the normals of {setting.array.path}", "drop orient")
    # The probe's sample and the own fits' reading are passes over the buckets too.
    plan = first.run("plan", lambda: planning.make(
        cloud, settings["preset"], "default", distinct=n, low=cloud.corner, k=settings["k"],
        iterations=settings["iterations"]))
    request = Request("robust", settings["preset"], "default", None, settings["params"],
                      settings["orient"], cloud.centre, report, started, settings["extras"])
    store = Files(folder)
    tiles = first.run("tiles", cloud.cells, plan, store, setting.tile_points)
    _, records = executor.run(plan, request, tiles, store, runner)
    clock = Clock(report, plan.iterations - 1, plan.iterations)
    paths = [Path(folder) / f"part_{i}.bin" for i in range(len(tiles))]
    parts = clock.run("parts", runner.map, "parts", plan.iterations - 1, plan.iterations,
                      _part, [(store, i, cloud.centre, setting.dtype, path, setting.blocks,
                               _columns(setting.array)) for i, path in enumerate(paths)])
    held = sum(found for _, found, _ in parts)
    return _Done(list(zip(paths, [counts for counts, _, _ in parts])), cloud.copies, stats(
        request, plan, cloud.rows, n, setting.n_threads, records, held,
        tiles={"count": len(tiles), "most_points": max(t.points for t in tiles),
               "scheduler": runner.name, "threads": runner.threads, "before": first.times,
               "after": clock.times}),
        (max((moved[0] for _, _, moved in parts), default=0.0),
         sum(moved[1] for _, _, moved in parts)))


def _file_settings(options, classified):
    """The options of a run from a file, checked as :func:`pssd_fast.denoise` checks them, and
    refused where they need every point at once; ``classified``: the file gives its own
    classification (LAS/LAZ), which ``classes`` then chooses from."""
    refused = [name for name in ("remove_outliers",) if options.get(name)]
    method = options.get("method", "robust")
    preset = options.get("preset", "default")
    if method != "robust":
        refused.append(f"method={method!r}")
    if preset == "paper":
        refused.append("preset='paper'")
    if refused:
        raise ValueError(f"denoise_file runs the default method (presets 'default' and "
                         f"'fast') and never holds every point; {' and '.join(refused)} "
                         f"need{'s' * (len(refused) == 1)} "
                         f"them all: read the file with pssd_fast.io.read, then pass its "
                         f"points (cloud.points) to pssd_fast.denoise or tiled.denoise")
    lidar.check_classes(classified or options.get("classification"), options.get("classes"))
    # denoise's own checks, on a cloud it does not run: what it would refuse, this refuses.
    # (The classes are denoise's, not the method's parameters.)
    return checked_options({name: value for name, value in options.items()
                            if name not in ("classification", "classes")})


def _columns(array):
    """What an output of ``array``'s kind takes of the results
    (:func:`pssd_fast.tiled.ondisk.part_dtype`): the coordinates of an ``.npy`` or Zarr
    array, every column of a LAS/LAZ file's table."""
    return ("xyz",) if isinstance(array, (ondisk.NpyFile, ondisk.ZarrFile)) else ondisk.TABLE


def _part(store, i, centre, dtype, path, blocks, columns, n_jobs):
    """Tile ``i``'s results as records of the output's ``columns``
    (:func:`pssd_fast.tiled.ondisk.part_dtype`) in a file at ``path`` sorted by the output's
    ``blocks``, the coordinates as :func:`pssd_fast.denoise` returns them (a task); the count
    of each block, the points the tile held in place, and the largest and the summed distance
    of its points from their input positions."""
    out = store.get(("out", i))
    points = store.get(("points", i), ("xyz", "row"))
    fields = {"xyz": (out["xyz"] + centre).astype(dtype).astype(np.float64)}
    moved = np.linalg.norm(fields["xyz"] - (points["xyz"] + centre), axis=1)
    if "nrm" in columns:
        nan = np.full(points["row"].shape[0], np.nan)
        fields.update(nrm=out["normals"].astype(dtype).astype(np.float64),
                      likelihood=out.get("likelihood", nan), feature=out.get("feature", nan),
                      displacement=np.linalg.norm(out["xyz"] - points["xyz"],
                                                  axis=1).astype(dtype))
    records = ondisk.part_records(ondisk.part_dtype(columns), points["row"], **fields)
    counts = ondisk.sorted_save(records, records["row"] // blocks.size, blocks.count, path)
    return counts, int(out["held"].sum()), (float(moved.max(initial=0.0)), float(moved.sum()))


def _write(runner, array, output, sources, blocks, dtype, folder, fields, copies, stage):
    """The sources' points in the input's rows (``copies``: the rows that take their first
    row's, :func:`pssd_fast.tiled.rows.write`): an ``.npy`` or Zarr array, or a copy of the
    LAS/LAZ input with those coordinates and the ``fields`` asked for. A Zarr or LAS/LAZ
    output is written from a table of the rows by one task. Returns the largest and the
    summed distance of the copies from their input positions."""
    n = array.shape[0]
    if isinstance(array, ondisk.NpyFile):
        return rows.write(runner, output, sources, blocks, n, dtype, copies=copies, stage=stage)
    table = folder / "rows.npy"
    columns = _columns(array)
    copied = rows.write(runner, table, sources, blocks, n, dtype, columns, copies, stage)
    runner.map("write file", *stage, _write_file, [(array, output, table, columns, fields)])
    return copied


def _write_file(array, output, table, columns, fields, n_jobs):
    """A Zarr or LAS/LAZ ``output`` of the rows of the ``.npy`` ``table`` (a task)."""
    table = ondisk.NpyFile(table, columns=ondisk.columns_width(columns))
    if isinstance(array, ondisk.ZarrFile):
        array.write(output, table)
    else:
        array.write(output, table, fields)


__all__ = ["FILE_KINDS", "LOCAL_SCHEDULERS", "denoise", "denoise_file"]
