"""Tiled runs on Dask, with the in-core result (docs/ALGORITHM.md, "Tiled runs").

The coarse-to-fine route of the presets "default" and "fast" touches every point twice: once
to average it into its grid cell, once to move it onto the fits of its nearest denoised cell
means. Between the two, the iterations run on the cell means alone (about a hundred thousand
where the noise spans several point spacings, whatever the number of points). So the points
are cut into tiles of whole cells, consecutive along the cells' Morton curve; each tile's cell
sums and each tile's final projection are Dask tasks, and the iterations, the collapse and the
fits run once, here. No tile needs a halo: a cell's points all lie in one tile and are summed
in the order the in-core run sums them, and each point's projection reads only the (shared)
fits. The result is bit-identical to :func:`pssd_fast.denoise`.

Dask is an optional dependency: ``pip install "pssd_fast[dask]"``.
"""
import importlib
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import atomic, core, duplicates, interop
from .. import classes as lidar
from .._threads import threads
from .._validation import (
    as_normals, as_points, auto, check_choice, check_flag, check_float, check_int, check_orient,
    check_size,
)
from ..denoise import METHOD_DEFAULTS
from ..graph import bounds
from ..pipelines import aware
from ..progress import Clock, reporter
from ..routes import coarse, edges
from ..routes import plan as planning
from ..routes.plan import PRESETS
from ..run import Input, Iterated, Request, check_distinct, iterate, result, stats
from . import halo, ondisk

#: Dask's local schedulers, by the names ``client`` takes for them.
LOCAL_SCHEDULERS = ("threads", "processes", "sync")
#: What :func:`denoise_file` reads and writes, by extension.
FILE_KINDS = {".npy": "npy", ".zarr": "zarr", ".las": "las", ".laz": "las"}
#: The feature-aware pipeline's parameters other than ``sigma_n`` and ``select_scales``, at
#: their defaults.
PARAMS = {"keep_normals": False, "shift_normals": True}
#: :func:`pssd_fast.denoise`'s parameters that tiled runs take at their default only (and,
#: at theirs, the method parameters of the paper's pipeline).
AT_DEFAULT = {"method": "robust", "k": "auto", "lam": None, "rebuild_graph": "auto",
              "remove_outliers": False, **PARAMS}
#: :func:`pssd_fast.denoise`'s parameters of LiDAR classes, which tiled runs take as it does.
CLASSES = ("classification", "classes")


def denoise(points, normals=None, *, tile_points=2_000_000, client=None, method="robust",
            iterations="auto", k="auto", lam=None, preset="default", rebuild_graph="auto",
            orient=None, remove_outliers=False, duplicate_tolerance=0.0, classification=None,
            classes=None, n_jobs=None, progress=None, **method_params):
    """Denoise ``points`` tile by tile on Dask; the result of :func:`pssd_fast.denoise`.

    Parameters
    ----------
    points : (n, 3) array_like
    normals : (n, 3) array_like, optional
        As in :func:`pssd_fast.denoise` (``points`` may be a cloud :mod:`pssd_fast.interop`
        converts).
    tile_points : int
        The most points a tile holds (a tile is never smaller than one grid cell).
    client : None, str or distributed.Client
        Where the tile tasks run: None or ``"threads"`` (Dask's local threads),
        ``"processes"`` or ``"sync"`` (Dask's local process pool, or this thread), a
        ``distributed.Client``, or the address of a Dask scheduler.
    preset : {"default", "fast"}
        The preset of :func:`pssd_fast.denoise`; its coarse-to-fine route is the one that
        tiles.
    iterations, orient, duplicate_tolerance, n_jobs, progress, **method_params
        As in :func:`pssd_fast.denoise`; of its method parameters ``sigma_n`` and
        ``select_scales`` (on the points only, as there; the plan of its walks is made before
        the tiles, and each task's halo covers the lists of ``4.5 k``). ``n_jobs`` is the
        threads of this machine that the tasks share: the local schedulers run at most that
        many tasks at once, with ``n_jobs // tasks`` threads each (``"sync"``: one task with
        all of them); on ``distributed`` each worker shares its own cores between the tasks it
        runs at once (its threads). ``progress`` also hears of each finished tile (stages
        ``tile_cells`` and ``tile_update``).
    classification, classes
        As in :func:`pssd_fast.denoise`: each class chosen runs on its own, tiled (a tiled run
        of its points alone), and the points of the other classes are kept as they are.
    method, k, lam, rebuild_graph, remove_outliers
        :func:`pssd_fast.denoise`'s, taken at their defaults only (as are ``keep_normals=False``
        and ``shift_normals=True``): tiled runs run the robust method of the feature-aware
        presets with the choices it makes in memory. Any other value raises ValueError naming
        it.

    Returns
    -------
    DenoiseResult
        Bit-identical to ``pssd_fast.denoise(points, normals, preset=preset, ...)``;
        ``stats["tiles"]`` gives the number of tiles, their most points, the scheduler and
        the ``threads`` the tasks took (``tasks_at_once`` and ``threads_per_task``: the most
        of each; on ``distributed`` the workers' threads in all and the largest share); with
        classes, those of the largest class's run, as :func:`pssd_fast.denoise` gives its
        ``stats``.

    Raises
    ------
    ValueError
        A parameter above set to another value than its default, or preset "fast" on a cloud
        it would iterate on its points (the noise small against the point spacing): it keeps
        its first lists through the iterations, which a tile's task of one iteration cannot;
        ``classification`` and ``classes`` as :func:`pssd_fast.denoise` refuses them.
    TypeError
        An unknown method parameter.
    ImportError
        Without Dask.

    Warns
    -----
    DenoiseWarning
        Where classes chosen by default are too small to denoise, as
        :func:`pssd_fast.denoise` warns.

    Examples
    --------
    Three tiles of at most 1,000 points, run in this thread, give the in-memory result bit for
    bit (``select_scales=False``: the walks' lists of ``4.5 k`` would make each tile's halo
    this small cloud's whole):

    >>> import numpy as np
    >>> import pssd_fast
    >>> from pssd_fast import datasets, tiled
    >>> points = datasets.make("cube", n_points=2000, seed=0).points
    >>> result = tiled.denoise(points, tile_points=1000, client="sync", select_scales=False)
    >>> result.stats["tiles"]["count"], result.stats["tiles"]["most_points"]
    (3, 960)
    >>> in_memory = pssd_fast.denoise(points, select_scales=False)
    >>> np.array_equal(result.points, in_memory.points)
    True
    """
    tile_points, iterations, sigma_n, select_scales = _settings(
        preset, tile_points, iterations, client, dict(
            method=method, k=k, lam=lam, rebuild_graph=rebuild_graph,
            remove_outliers=remove_outliers, **method_params))
    points = interop.coordinates(points)
    if classes is not None or classification is not None:
        return _by_class(points, normals, classification, classes, {
            "tile_points": tile_points, "client": client, "iterations": iterations,
            "preset": preset, "orient": orient, "duplicate_tolerance": duplicate_tolerance,
            "n_jobs": n_jobs, "progress": progress, **method_params})
    report = reporter(progress)
    pts, dtype = as_points(points)
    n = pts.shape[0]
    check_size(n)
    given = None if normals is None else as_normals(normals, n)
    if orient is not None:
        orient = check_orient(orient)
        if given is not None:
            raise ValueError("orient applies to estimated normals; the given normals keep their "
                             "signs (pass normals=None or drop orient)")
    duplicate_tolerance = duplicates.check_tolerance(duplicate_tolerance)
    started = time.perf_counter()
    n_input = n
    order, groups = duplicates.ordered(pts, duplicate_tolerance)
    n = check_distinct(order.shape[0], n_input, None)
    centre = 0.5 * np.add(*bounds(pts))
    current = core.relative_rows(pts, order, centre)
    given = None if given is None else given[order]
    request = Request("robust", preset, "aware", None, {**PARAMS, "sigma_n": sigma_n}, orient,
                      centre, report, started)
    with threads(n_jobs) as n_threads, _Runner(client, n_threads, report) as runner:
        plan = planning.make(current, given, preset, distinct=n, iterations=iterations,
                             layout=lambda noise, key: coarse.layout(current, noise, key),
                             select_scales=select_scales, sigma_n=sigma_n,
                             shift_normals=PARAMS["shift_normals"])
        request.params["select_scales"] = plan.select_scales
        if plan.cells is None:
            _check_points_route(preset)
            done, spans = _points(current, given, plan, request, runner, tile_points)
            tiled = {"count": len(spans), "most_points": max(b - a for a, b in spans),
                     "route": "halo"}
        else:
            done, tiled = _cells(current, given, plan, request, runner, tile_points, order)
    tiled.update(scheduler=runner.name, threads=runner.threads)
    return result(Input(pts, dtype, order, groups), done, centre, np.arange(n_input), None,
                  stats(request, plan, n_input, n, n_threads, done.records,
                        int(done.held.sum()), tiles=tiled))


def _by_class(points, normals, classification, classes, options):
    """:func:`denoise` of each class that ``classification`` and ``classes`` choose on its
    own, the other points kept as they are, as :func:`pssd_fast.denoise` keeps them."""
    started = time.perf_counter()
    pts, dtype = as_points(points)
    return lidar.denoise_each(pts, dtype, normals, classification, classes,
                              {"preset": options["preset"]},
                              lambda part, given: denoise(part, given, **options), started,
                              stacklevel=3)


def _points(current, given, plan, request, runner, tile_points):
    """:func:`denoise` on the points (tiles with halos): an
    :class:`~pssd_fast.run.Iterated` and the tiles' rank ranges."""
    spans = halo.tiles(current.shape[0], tile_points)
    centroid = current.mean(axis=0)
    reach = plan.k if plan.walks is None else int(plan.walks.lengths[-1])
    done = halo.iterate(current, given, plan, request.params["sigma_n"], spans,
                        halo.first_width(plan.probe["probe_radius"], plan.probe["probe_k"],
                                         reach), runner)
    if request.orient is not None:
        # Propagation over the whole cloud's lists does not tile: one by one.
        halo.orient_pointwise(done.points, done.normals,
                              _relative(request.orient, request.centre), centroid)
    return done, spans


def _cells(current, given, plan, request, runner, tile_points, order):
    """:func:`denoise` on the coarse-to-fine route (tiles of whole cells): an
    :class:`~pssd_fast.run.Iterated` of every point (moved in ``current``, in place) and the
    tiles' description."""
    (rows, starts), edge = plan.layout[:2], plan.layout[2]
    iterations, sigma_n = plan.iterations, request.params["sigma_n"]
    tiles = _tiles(starts, tile_points)
    parts = [rows[starts[c0]:starts[c1]] for c0, c1 in tiles]
    sums = runner.map("tile_cells", 1, iterations, _tile_cells, [
        (current[part], None if given is None else given[part],
         starts[c0:c1 + 1] - starts[c0]) for part, (c0, c1) in zip(parts, tiles)])
    cells = coarse.Cells(np.concatenate([s[0] for s in sums]),
                         None if given is None else np.concatenate([s[1] for s in sums]),
                         np.diff(starts), edge, plan.k, coarse.COARSE[plan.cells]["surface_k"],
                         plan.rebuild_graph)
    means = iterate(cells.points, cells.normals, plan, request, cells.counts)
    surface, surface_normals, extra = coarse.collapse(cells, means.points, means.normals,
                                                      means.extra)
    clock = Clock(request.report, iterations - 1, iterations)
    coef, rms, degree = coarse.fit_surface(surface, surface_normals, cells.surface_k,
                                           sigma_n, clock)
    moved = runner.map("tile_update", iterations, iterations, _tile_update, [
        (current[part], surface, surface_normals, coef) for part in parts])
    every = np.concatenate(parts)
    fine = current.copy() if plan.edges is not None else None
    current[every] = np.concatenate([m[0] for m in moved])
    held = np.empty(current.shape[0], np.bool_)
    held[every] = np.concatenate([m[1] for m in moved])
    nearest = np.empty(current.shape[0], np.int64)
    nearest[every] = np.concatenate([m[2] for m in moved])
    out_normals = surface_normals[nearest]
    if plan.edges is not None:
        # In memory, as denoise runs it: the same rows in, the same bits out.
        edges.finish(plan.edges, fine, current, out_normals, held, nearest,
                     edges.zones(surface, extra[1], plan.edges["radius"]), order, given,
                     False, sigma_n, clock)
    means.records[-1]["times"].update(clock.times)
    plan.probe["coarse"] = coarse.describe(plan.noise, edge, cells.counts, surface,
                                           cells.surface_k,
                                           coarse.fit_record(held, nearest, rms, degree))
    tiled = {"count": len(tiles), "most_points": int(max(len(p) for p in parts)),
             "route": "cells"}
    return Iterated(current, out_normals, tuple(x[nearest] for x in extra), means.records,
                    held), tiled


def denoise_file(source, destination, *, tile_points=2_000_000, client=None, method="robust",
                 iterations="auto", k="auto", lam=None, preset="default",
                 rebuild_graph="auto", orient=None, remove_outliers=False,
                 duplicate_tolerance=0.0, classification=None, classes=None,
                 fields=(), n_jobs=None, progress=None, scratch=None,
                 overwrite=False, **method_params):
    """Denoise the points of an ``.npy``, Zarr or LAS/LAZ file into another, out of core, tile
    by tile on Dask.

    The input is read in chunks; the points are binned into tile files in a scratch folder,
    each task reads one tile (and, on a cloud iterated on its points, the halo of the tile
    from the others), and the output is written in the input's row order. Memory follows
    ``tile_points`` (and, on the coarse-to-fine route, the number of grid cells), not the
    number of points. The result is that of :func:`pssd_fast.denoise`, bit for bit.

    Parameters
    ----------
    source : path-like
        An ``.npy`` file of a real ``(n, 3)`` array, a Zarr array of that shape (or a Zarr
        group holding one as ``points``; ``pip install "pssd_fast[zarr]"``), or a LAS/LAZ
        file (its ``nx``, ``ny``, ``nz``, where it has them, are the given normals; its
        ``classification`` field gives each point's class, see ``classes``).
    destination : path-like
        Of the kind of ``source``, written only when complete: the denoised ``(n, 3)`` points
        in the input's rows (``.npy``, or a Zarr array of the input's chunks), float32 for
        float32 input and float64 otherwise; or a ``.las``/``.laz`` file: the input with the
        denoised coordinates (quantised as :func:`pssd_fast.io.write` quantises them), the
        ``fields`` asked for (as ``pssd denoise --fields`` writes them: ``nx``, ``ny``, ``nz``
        for the normals, float32 extra bytes where new), every other record byte, the header,
        the VLRs and the EVLRs as read.
    tile_points, client, preset, iterations, orient, n_jobs, progress, **method_params
        As in :func:`denoise`; progress also hears of the passes over the file (``buckets``,
        ``tiles``) and of the output (``write``).
    duplicate_tolerance : float
        As in :func:`pssd_fast.denoise`: the rows at one position are merged while the file
        is binned (each bucket holds whole positions), and take their first row's output.
    classification : array_like of int, shape (n,), optional
        Of an ``.npy`` or Zarr input, as in :func:`pssd_fast.denoise`. A LAS/LAZ input's
        classes are its ``classification`` field (read first, one byte a point), which it
        refuses.
    classes : iterable of int, "each" or "all", optional
        As in :func:`pssd_fast.denoise`, of ``classification`` or a LAS/LAZ file's field: by
        default the surface classes present, and a file of classes 0 and 1 only as one cloud;
        ``"all"``: every point as one cloud. Each class chosen runs out of core on its own (a
        run reads the file three times and takes the rows of its class), and the rows of the
        other classes keep their coordinates (a LAS/LAZ record byte for byte), their normals
        as read, NaN likelihood and feature intensity and zero displacement, as
        ``pssd denoise`` writes them in memory.
    method, k, lam, rebuild_graph, remove_outliers
        As in :func:`denoise`: their defaults only.
    fields : sequence of str
        LAS/LAZ output: which of ``"likelihood"``, ``"feature_intensity"``,
        ``"displacement"`` and ``"normals"`` to add (default none: the output has the input's
        dimensions only; a file's own normals are always updated).
    scratch : path-like, optional
        Where the scratch folder goes (default: beside ``destination``); with a cluster, a
        folder every worker reads and writes. It is removed on success, on failure and on
        interrupt.
    overwrite : bool
        Replace an existing ``destination``.

    Returns
    -------
    dict
        The run's ``stats``, as :func:`denoise` gives them (with classes, as
        :func:`pssd_fast.denoise` gives them: ``stats["classes"]`` says what ran).

    Raises
    ------
    ValueError
        Bad input, unknown fields, other formats, a parameter :func:`denoise` takes at its
        default only, ``fast`` on a cloud it would iterate on its points (see
        :func:`denoise`), too few distinct positions, or ``classification`` and ``classes``
        as :func:`pssd_fast.denoise` refuses them (``classification`` with a LAS/LAZ file).
    FileExistsError
        ``destination`` exists and ``overwrite`` is False: checked first, and again by the
        final rename, which never replaces what another writer put there meanwhile.

    Warns
    -----
    DenoiseWarning
        Where classes chosen by default are too small to denoise, as
        :func:`pssd_fast.denoise` warns.

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
    ...     stats = tiled.denoise_file(scan, clean, tile_points=1000, client="sync",
    ...                                select_scales=False)
    ...     denoised = np.load(clean)
    >>> denoised.shape, denoised.dtype
    ((2000, 3), dtype('float32'))
    >>> stats["n_points"], stats["tiles"]["count"], stats["plan"]["route"]
    (2000, 3, 'points')
    """
    source, destination = Path(source), Path(destination)
    kinds = {path: FILE_KINDS.get(path.suffix.lower()) for path in (source, destination)}
    if None in kinds.values() or len(set(kinds.values())) > 1:
        raise ValueError(f"denoise_file reads .npy into .npy, Zarr into Zarr, or .las/.laz "
                         f"into .las/.laz; got {source.name} and {destination.name} (other "
                         f"formats: pssd_fast.io.read, then denoise)")
    tile_points, iterations, sigma_n, select_scales = _settings(
        preset, tile_points, iterations, client, dict(
            method=method, k=k, lam=lam, rebuild_graph=rebuild_graph,
            remove_outliers=remove_outliers, **method_params))
    lidar.check_classes(classification, classes)
    if kinds[source] == "las" and classification is not None:
        raise ValueError(f"the classes of {source.name} are its classification field; pass "
                         f"classes=... alone")
    orient = None if orient is None else check_orient(orient)
    duplicate_tolerance = duplicates.check_tolerance(duplicate_tolerance)
    unknown = sorted(set(fields) - set(ondisk.RESULT_FIELDS))
    if unknown:
        raise ValueError(f"unknown field(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(ondisk.RESULT_FIELDS)}")
    exists = f"{destination} exists; pass overwrite=True to replace it"
    if destination.exists() and not overwrite:
        raise FileExistsError(exists)
    if destination.resolve() == source.resolve():
        raise ValueError(f"the output {destination} would overwrite the input")
    array = {"npy": ondisk.NpyFile, "las": ondisk.LasFile, "zarr": ondisk.ZarrFile}[
        kinds[source]](source)
    labels = _file_labels(array, classification, classes)
    runs, small, least = [None], [], None
    if labels is not None:
        codes, counts = np.unique(labels, return_counts=True)
        least = lidar.least_points({"preset": preset})
        found, small = lidar.choose(codes, counts, classes, least)
        if found is None:
            labels = None  # classes 0 and 1 only: no classification
        else:
            runs = found
    lidar.warn_small(small, least, stacklevel=2)
    dtype = np.dtype(np.float32) if array.dtype == np.float32 else np.dtype(np.float64)
    report = reporter(progress)
    started = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix="pssd_tiles_", dir=scratch or destination.parent))
    # Beside the destination, so that the last rename stays on one file system.
    output = atomic.temporary(destination)
    setting = _FileRun(array, tile_points, duplicate_tolerance, iterations, preset,
                       select_scales, sigma_n, orient, report)
    try:
        with threads(n_jobs) as n_threads, _Runner(client, n_threads, report) as runner:
            done = []
            for code in runs:
                if code is None:
                    done.append((None, *_file_run(setting, None, folder, runner, n_threads,
                                                  started)))
                    continue
                try:
                    done.append((code, *_file_run(
                        setting, lambda a, b, code=code: labels[a:b] == code,
                        folder / f"class_{code}", runner, n_threads, time.perf_counter())))
                except ValueError as exc:
                    raise ValueError(f"the points of class {code}: {exc}") from exc
            parts = [path for _, paths, _, _ in done for path in paths]
            if labels is not None:
                kept = folder / "kept.bin"
                ondisk.unmoved(array, lambda a, b: ~np.isin(labels[a:b], runs), kept)
                parts.append(kept)
            last = done[-1][3]
            clock = Clock(report, last["n_iterations"] - 1, last["n_iterations"])
            clock.run("write", _write, array, output, parts, array.shape[0], dtype, folder,
                      fields, [copies for _, _, copies, _ in done if copies is not None])
            atomic.sync(output)
            atomic.replace(output, destination, overwrite=overwrite, exists_message=exists)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        if output.is_dir():
            shutil.rmtree(output, ignore_errors=True)
        output.unlink(missing_ok=True)
    if labels is None:
        found = done[0][3]
        found["total_seconds"] = time.perf_counter() - started
    else:
        found = lidar.summary(
            [(code, run["n_points"], run) for code, _, _, run in done],
            int(array.shape[0] - sum(run["n_points"] for *_, run in done)), small, runs,
            started)
    found["iterations"][-1]["times"].update(clock.times)
    return found


class _FileRun(NamedTuple):
    """What each run of :func:`denoise_file` takes: the input ``array`` and the call's
    settings, checked."""
    array: object
    tile_points: int
    duplicate_tolerance: float
    iterations: object
    preset: str
    select_scales: object
    sigma_n: float
    orient: object
    report: object


def _file_labels(array, classification, classes):
    """The class of each row of ``array``: a LAS/LAZ file's classification field (unless
    ``classes`` is ``"all"``), or ``classification`` checked; None for one cloud."""
    if isinstance(classes, str) and classes == "all":
        return None
    if isinstance(array, ondisk.LasFile):
        return array.classification()
    if classification is None:
        return None
    return lidar.check_labels(classification, array.shape[0])


def _file_run(setting, keep, folder, runner, n_threads, started):
    """One run of :func:`denoise_file` on the rows of ``setting.array`` that ``keep`` selects
    (``keep(start, stop)``: a mask of rows ``start..stop-1``; None: every row), its scratch
    files in ``folder``: the part files, the file of rows set aside as copies (or None) and
    the run's ``stats``."""
    folder.mkdir(exist_ok=True)
    report, orient = setting.report, setting.orient
    # The plan may change the preset's iterations; the buckets come before it.
    first = Clock(report, 0, setting.iterations or PRESETS[setting.preset]["iterations"])
    cloud = first.run("buckets", ondisk.Buckets, setting.array, folder, setting.tile_points,
                      setting.duplicate_tolerance, keep)
    n = check_distinct(cloud.shape[0], cloud.rows, None)
    given = cloud.normals
    if given is not None and orient is not None:
        raise ValueError(f"orient applies to estimated normals; {setting.array.path} has "
                         f"normals, whose signs are kept (drop orient)")
    plan = planning.make(cloud, given, setting.preset, distinct=n,
                         iterations=setting.iterations, layout=cloud.layout,
                         select_scales=setting.select_scales, sigma_n=setting.sigma_n,
                         shift_normals=PARAMS["shift_normals"])
    request = Request("robust", setting.preset, "aware", None,
                      {**PARAMS, "sigma_n": setting.sigma_n,
                       "select_scales": plan.select_scales},
                      orient, cloud.centre, report, started)
    first.iterations = plan.iterations
    if plan.cells is None:
        _check_points_route(setting.preset)
        spans = halo.tiles(n, setting.tile_points)
        parts, records, held = _file_points(cloud, spans, plan, request, folder, runner,
                                            first)
        tiled = {"count": len(spans), "most_points": max(b - a for a, b in spans),
                 "route": "halo"}
    else:
        parts, records, tiled, held = _file_cells(cloud, plan, request, folder, runner,
                                                  first, setting.tile_points)
    tiled.update(scheduler=runner.name, threads=runner.threads)
    records[0]["times"].update(first.times)
    return parts, cloud.copies if cloud.duplicates else None, stats(
        request, plan, cloud.rows, n, n_threads, records, held, tiles=tiled)


def _file_cells(cloud, plan, request, folder, runner, first, tile_points):
    """The coarse-to-fine route of :func:`denoise_file` (``plan``'s cells): the part files,
    the iterations' records, the tiles' description and the number of points held."""
    (codes, counts), edge = plan.layout[:2], plan.layout[2]
    iterations, sigma_n = plan.iterations, request.params["sigma_n"]
    starts = np.concatenate(([0], np.cumsum(counts)))
    tiles = _tiles(starts, tile_points)
    paths = first.run("tiles", cloud.tiles, folder, codes[[c0 for c0, _ in tiles]], edge)
    sums = runner.map("tile_cells", 1, iterations, _file_cells_task,
                      [(path, cloud.centre, cloud.dtype) for path in paths])
    given = cloud.normals is not None
    cells = coarse.Cells(np.concatenate([s[0] for s in sums]),
                         np.concatenate([s[1] for s in sums]) if given else None, counts, edge,
                         plan.k, coarse.COARSE[plan.cells]["surface_k"], plan.rebuild_graph)
    means = iterate(cells.points, cells.normals, plan, request, cells.counts)
    records = means.records
    surface, surface_normals, extra = coarse.collapse(cells, means.points, means.normals,
                                                      means.extra)
    clock = Clock(request.report, iterations - 1, iterations)
    coef, rms, degree = coarse.fit_surface(surface, surface_normals, cells.surface_k, sigma_n,
                                           clock)
    code = (None if plan.edges is None
            else edges.zones(surface, extra[1], plan.edges["radius"]))
    parts = [folder / f"part_{i}.bin" for i in range(len(paths))]
    fits = runner.map("tile_update", iterations, iterations, _file_update, [
        (path, part, cloud.centre, cloud.dtype, surface, surface_normals, coef, extra, rms,
         degree, code) for path, part in zip(paths, parts)])
    held = sum(f[0] for f in fits)
    if plan.edges is not None:
        held += _file_edges(plan.edges, [f[3] for f in fits], parts, runner, cloud.centre,
                            sigma_n, clock, iterations)
    records[-1]["times"].update(clock.times)
    fit = coarse.fit_summary(sum(f[0] for f in fits), sum(f[1] for f in fits),
                             np.sum([f[2] for f in fits], axis=0), cloud.shape[0])
    plan.probe["coarse"] = coarse.describe(plan.noise, edge, counts, surface, cells.surface_k,
                                           fit)
    tiled = {"count": len(tiles), "most_points": int(max(starts[c1] - starts[c0]
                                                         for c0, c1 in tiles)),
             "route": "cells"}
    return parts, records, tiled, held


def _file_edges(setting, zones, parts, runner, centre, sigma_n, clock, iterations):
    """The edges route's pass of :func:`denoise_file`: the zones the tiles gathered, passed
    as in core (:func:`pssd_fast.routes.edges.gathered`), and the flagged points' records
    replaced in their parts. Returns the points it held that the cells had not (the pass's
    counts go into ``setting``)."""
    def joined(name):
        return np.concatenate([zone[name] for zone in zones])

    rows, fine = joined("rows"), joined("fine")
    picked, moved, out, held_now = edges.gathered(
        setting, rows, fine, joined("placed"), joined("normals"), joined("flagged"),
        None if zones[0]["given"] is None else joined("given"), False, sigma_n, clock)
    rows = rows[picked]
    part_of = np.repeat(np.arange(len(zones)), [zone["rows"].shape[0] for zone in zones])
    part_of = part_of[picked]
    displacement = np.linalg.norm(moved - fine[picked], axis=1)
    runner.map("tile_edges", iterations, iterations, _file_patch, [
        (parts[i], rows[part_of == i], moved[part_of == i] + centre, out[part_of == i],
         displacement[part_of == i]) for i in np.unique(part_of)])
    return int((held_now & ~joined("held")[picked]).sum())


def _file_patch(part, rows, points, normals, displacement, n_jobs):
    """The records of ``rows`` in a ``part`` file given new coordinates, normals and
    displacements (the edges route's pass)."""
    records = np.fromfile(part, ondisk.PART)
    by_row = np.argsort(records["row"])
    at = by_row[np.searchsorted(records["row"], rows, sorter=by_row)]
    records["xyz"][at] = points
    records["nrm"][at] = normals
    records["displacement"][at] = displacement
    ondisk.save(records, part)


def _file_points(cloud, spans, plan, request, folder, runner, first):
    """The iterations of :func:`denoise_file` on the points, tiles with halos
    (:mod:`pssd_fast.tiled.halo`) over the rank ranges ``spans``, each tile's points in a state
    file between iterations: the part files, the iterations' records and the number of points
    held in any iteration."""
    k, iterations, walks = plan.k, plan.iterations, plan.walks
    sigma_n = request.params["sigma_n"]
    reach = k if walks is None else int(walks.lengths[-1])
    width = halo.first_width(plan.probe["probe_radius"], plan.probe["probe_k"], reach)
    n = cloud.shape[0]
    paths = [folder / f"state_0_{i}.bin" for i in range(len(spans))]
    pieces, total = first.run("tiles", cloud.states, paths, spans)
    given = cloud.normals is not None
    centroid = None if given else total / n
    widths = [width] * len(spans)
    records = []
    for t in range(iterations):
        started = time.perf_counter()
        last = t == iterations - 1
        outputs = [folder / (f"part_{i}.bin" if last else f"state_{(t + 1) % 2}_{i}.bin")
                   for i in range(len(spans))]

        def sources(i, width):
            region = halo.widened(pieces[i], width)
            return _sources(i, region, pieces, paths, spans), (
                None if halo.covers(region, _union(pieces)) else region)

        radius = None
        if last:
            nearest = [folder / f"nearest_{i}.bin" for i in range(len(spans))]
            halo.each_tile(runner, "tile_spacing", t, iterations, _file_spacing, widths,
                           lambda i, width: ((paths[i], *sources(i, width)), n, k, nearest[i]))
            radius = aware.region_radius(halo.pairwise_mean(
                ondisk.ranked(nearest, spans, np.dtype(np.float64)), n))
        out = halo.each_tile(runner, "tile_step", t, iterations, _file_step, widths,
                             lambda i, width: ((paths[i], *sources(i, width)), t == 0, given,
                                               centroid, n, halo.Fit(
                                                   k, sigma_n, radius,
                                                   None if walks is None else walks.at(t)),
                                               outputs[i], cloud.centre))
        pieces = [o.pop("boxes") for o in out]
        records.append(halo.record(out, n, widths, started))
        paths = outputs
    dbar = halo.pairwise_mean(ondisk.ranked(paths, spans, ondisk.PART, "likelihood"), n)
    runner.map("finish", iterations, iterations, _file_finish, [
        (path, dbar, cloud.centre, _relative(request.orient, cloud.centre), centroid)
        for path in paths])
    return paths, records, sum(o["held_points"] for o in out)


def _union(pieces):
    """The box around all the boxes of ``pieces``."""
    every = np.concatenate(pieces)
    return every[:, 0].min(axis=0), every[:, 1].max(axis=0)


def _sources(i, region, pieces, paths, spans):
    """What tile ``i``'s task reads besides its own file: ``(path, [(start, stop), ...])``
    of each other tile's runs whose box meets the boxes ``region``."""
    found = []
    for j, (found_boxes, path, (a, b)) in enumerate(zip(pieces, paths, spans)):
        if j == i:
            continue
        meets = ((found_boxes[:, None, 0] <= region[None, :, 1]).all(axis=2)
                 & (found_boxes[:, None, 1] >= region[None, :, 0]).all(axis=2)).any(axis=1)
        ends = halo.cuts(b - a)
        hits = np.flatnonzero(meets)
        if hits.size:
            # Consecutive runs read as one range.
            breaks = np.flatnonzero(np.diff(hits) > 1)
            firsts = np.concatenate((hits[:1], hits[breaks + 1]))
            lasts = np.concatenate((hits[breaks], hits[-1:]))
            found.append((path, [(int(ends[f]), int(ends[l + 1]))
                                 for f, l in zip(firsts, lasts)]))
    return found


def _file_spacing(reads, n, k, output, n_jobs):
    """:func:`pssd_fast.tiled.halo.spacing` of a tile in its state file, saved to ``output``;
    None when the halo is too thin. ``reads``: the tile's state file, what it reads of the
    others' (:func:`_sources`) and its halo's boxes."""
    own_path, sources, region = reads
    own = np.fromfile(own_path, ondisk.STATE)
    points = ondisk.gather(own, sources, region)
    nearest = halo.spacing(halo.Tile(np.ascontiguousarray(points["xyz"]), own.shape[0], n,
                                     region), k, n_jobs)
    if nearest is None:
        return None
    ondisk.save(nearest, output)
    return True


def _file_step(reads, first, given, centroid, n, fit, output, centre, n_jobs):
    """:func:`pssd_fast.tiled.halo.step` of a tile in its state file (``reads``, as
    :func:`_file_spacing` takes it); the moved points saved to ``output``, a state file, or on
    the last iteration (``fit.radius`` given) a part file whose
    likelihood column holds the residual for now. Returns the step's counts and the
    :func:`~pssd_fast.tiled.halo.boxes` of the moved points (on the last iteration also the count
    of its points held in any iteration), or None when the halo is too thin."""
    own_path, sources, region = reads
    own = np.fromfile(own_path, ondisk.STATE)
    points = ondisk.gather(own, sources, region)
    # The first iteration's normals: the file's (given), else PCA's hinted by the centroid.
    found = halo.step(halo.Tile(np.ascontiguousarray(points["xyz"]), own.shape[0], n, region),
                      None if first and not given else np.ascontiguousarray(points["nrm"]),
                      first and given, centroid, fit, n_jobs)
    if found is None:
        return None
    moved, normals = found.pop("moved"), found.pop("normals")
    rms, feature = found.pop("rms"), found.pop("feature")
    held = own["held"] | found["held"]
    if fit.radius is None:
        state = own.copy()
        state["xyz"], state["nrm"], state["held"] = moved, normals, held
        ondisk.save(state, output)
    else:
        found["held_points"] = int(held.sum())
        ondisk.save(ondisk.part_records(own["row"], moved + centre, normals, rms, feature,
                                        np.linalg.norm(moved - own["start"], axis=1)), output)
    found["boxes"] = halo.boxes(moved)
    return found


def _file_finish(part, dbar, centre, orient, centroid, n_jobs):
    """A part file's residuals turned into likelihoods, relative to the cloud's ``dbar``, and
    its normals turned to face ``orient`` one by one (see :func:`denoise`)."""
    with threads(n_jobs):
        records = np.fromfile(part, ondisk.PART)
        records["likelihood"] = core.sampling_likelihood(records["likelihood"], "exp", dbar)[0]
        if orient is not None:
            halo.orient_pointwise(records["xyz"] - centre, records["nrm"], orient, centroid)
        ondisk.save(records, part)


def _relative(orient, centre):
    """``orient`` in the frame of points relative to ``centre`` (a name is kept)."""
    return orient if orient is None or isinstance(orient, str) else orient - centre


def _write(array, output, parts, n, dtype, folder, fields, copies):
    """The parts' points in the input's rows (``copies``: the files of the rows that take
    their first row's, :func:`pssd_fast.tiled.ondisk.write_rows`): an ``.npy`` or Zarr array, or
    a copy of the LAS/LAZ input with those coordinates and the ``fields`` asked for."""
    if isinstance(array, ondisk.NpyFile):
        ondisk.write_rows(output, parts, n, dtype, copies=copies)
        return
    table = folder / "rows.npy"
    if isinstance(array, ondisk.ZarrFile):
        ondisk.write_rows(table, parts, n, dtype, copies=copies)
        array.write(output, ondisk.NpyFile(table))
        return
    ondisk.write_rows(table, parts, n, dtype, ondisk.TABLE, copies)
    array.write(output, ondisk.NpyFile(table, columns=ondisk.columns_width(ondisk.TABLE)),
                fields)


def _settings(preset, tile_points, iterations, client, options):
    """The arguments both entry points share, checked: ``tile_points``, the iterations,
    ``sigma_n`` and ``select_scales`` (None: ``"auto"``); ``options``: the rest of
    :func:`pssd_fast.denoise`'s parameters, refused unless at :data:`AT_DEFAULT`."""
    check_choice(preset, "preset", tuple(coarse.COARSE))
    if not (client is None or isinstance(client, str) or hasattr(client, "submit")):
        raise TypeError(f"client must be None, one of {LOCAL_SCHEDULERS}, a scheduler address "
                        f"or a distributed.Client; got {client!r}")
    robust = METHOD_DEFAULTS["robust"]
    unknown = sorted(set(options) - set(AT_DEFAULT) - set(robust))
    if unknown:
        raise TypeError(f"unknown parameter(s) {', '.join(unknown)}; valid: "
                        f"{', '.join(sorted({*AT_DEFAULT, *robust, *CLASSES} - set(PARAMS)))}")
    refused = [f"{name}={value!r}" for name, value in options.items()
               if name not in ("sigma_n", "select_scales")
               and not _at_default(value, AT_DEFAULT.get(name, robust.get(name)))]
    if refused:
        raise ValueError(f"tiled runs take the robust method of the presets default and fast "
                         f"with the choices it makes in memory; they do not take "
                         f"{', '.join(refused)} (use pssd_fast.denoise for those)")
    return (check_int(tile_points, "tile_points", minimum=1),
            auto(iterations, lambda v: check_int(v, "iterations", minimum=1)),
            check_float(options.get("sigma_n", robust["sigma_n"]), "sigma_n", positive=True),
            check_flag(options.get("select_scales"), "select_scales"))


def _at_default(value, default):
    """Whether ``value`` is the parameter's ``default`` (``"auto"`` and None alike)."""
    if default == "auto" or default is None:
        return auto(value) is None
    return isinstance(value, type(default)) and value == default


def _check_points_route(preset):
    """The error for ``fast`` on a cloud it iterates on its points: it keeps its first lists
    through the iterations, which a tile's task of one iteration cannot."""
    if not PRESETS[preset]["rebuild_graph"]:
        raise ValueError(f"preset {preset!r} finds no grid cells in this cloud and would "
                         f"iterate on its points with the first iteration's lists; tiled runs "
                         f"query them anew in each iteration: use preset 'default'")


def _file_cells_task(path, centre, dtype, n_jobs):
    """The cell means of a tile file, and their mean normals (or None)."""
    with threads(n_jobs):
        _, codes, points, normals = ondisk.read_tile(path, centre, dtype)
        return core.cell_means(points, normals, *coarse.group_codes(codes))


def _file_update(path, part, centre, dtype, surface, normals, coef, extra, rms, degree, code,
                 n_jobs):
    """A tile file's points moved onto the fits, saved to ``part`` with the normal, the
    likelihood and the feature intensity of their nearest denoised mean; returns the held
    points, the sum of the nearest fits' residuals, their degrees and, with the zone ``code``
    of the edges route (:func:`pssd_fast.routes.edges.zones`, else None), the tile's zone:
    its points' input ``rows``, ``fine`` and ``placed`` positions, ``normals``, whether
    ``flagged`` and whether ``held``, and their ``given`` normals (or None)."""
    with threads(n_jobs):
        rows, _, points, given = ondisk.read_tile(path, centre, dtype)
        moved, held, nearest = coarse.onto_fits(points, surface, normals, coef)
        ondisk.save(ondisk.part_records(rows, moved + centre, normals[nearest],
                                        extra[0][nearest], extra[1][nearest],
                                        np.linalg.norm(moved - points, axis=1)), part)
        zone = None
        if code is not None:
            inside = np.flatnonzero(code[nearest] != edges.OUTSIDE)
            zone = {"rows": rows[inside], "fine": points[inside], "placed": moved[inside],
                    "normals": normals[nearest[inside]],
                    "flagged": code[nearest[inside]] == edges.FLAGGED, "held": held[inside],
                    "given": None if given is None else given[inside]}
        return (int(held.sum()), float(rms[nearest].sum()),
                np.bincount(degree[nearest], minlength=7), zone)


def _tiles(starts, tile_points):
    """Consecutive ranges ``(c0, c1)`` of the cells of ``starts``, each holding at most
    ``tile_points`` points (or one cell)."""
    tiles = []
    c0 = 0
    m = starts.shape[0] - 1
    while c0 < m:
        c1 = int(np.searchsorted(starts, starts[c0] + tile_points, side="right")) - 1
        c1 = min(max(c1, c0 + 1), m)
        tiles.append((c0, c1))
        c0 = c1
    return tiles


def _tile_cells(points, normals, starts, n_jobs):
    """A tile's cell means and mean normals (None without normals)."""
    with threads(n_jobs):
        return core.cell_means(points, normals, np.arange(points.shape[0]), starts)


def _tile_update(points, surface, normals, coef, n_jobs):
    """A tile's points moved onto the fits: moved, held, nearest mean."""
    with threads(n_jobs):
        return coarse.onto_fits(points, surface, normals, coef)


class _Runner:
    """Runs each tile's task on the chosen scheduler and reports each finished tile.

    The tasks that run at once share the cores: on the local schedulers at most ``n_jobs``
    tasks at once with ``n_jobs // tasks`` threads each (``"sync"``: one task with all of
    them), on ``distributed`` each worker's cores split between its threads' tasks
    (:func:`_worker_threads`). ``threads`` records what the tasks took, for ``stats``.
    """

    def __init__(self, client, n_jobs, report):
        self.client = client
        self.n_jobs = n_jobs
        self.report = report
        self.own = None
        self.name = "threads" if client is None else (
            client if client in LOCAL_SCHEDULERS else "distributed")
        self.threads = None

    def __enter__(self):
        try:
            importlib.import_module("distributed" if self.name == "distributed" else "dask")
        except ImportError as err:
            raise ImportError("tiled runs need Dask: pip install 'pssd_fast[dask]'") from err
        if isinstance(self.client, str) and self.name == "distributed":
            import distributed

            self.own = self.client = distributed.Client(self.client)
        return self

    def __exit__(self, *exc):
        if self.own is not None:
            self.own.close()

    def _record(self, at_once, per_task):
        """Keep the most tasks at once and the most threads a task took."""
        before = self.threads or {"tasks_at_once": 0, "threads_per_task": 0}
        self.threads = {"tasks_at_once": max(before["tasks_at_once"], at_once),
                        "threads_per_task": max(before["threads_per_task"], per_task)}

    def map(self, stage, iteration, iterations, func, argsets):
        """``func(*args, n_jobs)`` for each of ``argsets``, results in their order."""
        total = len(argsets)
        done = [0, time.perf_counter()]

        def finished():
            # Each tile is reported as a stage: the time since the one before.
            now = time.perf_counter()
            done[0] += 1
            if self.report is not None:
                self.report(iteration, iterations, f"{stage} {done[0]}/{total}", now - done[1])
            done[1] = now

        if self.name == "distributed":
            import distributed

            slots = {address: worker["nthreads"]
                     for address, worker in self.client.scheduler_info()["workers"].items()}
            # A worker lost meanwhile is left out here; Dask reruns its tasks elsewhere.
            shares = self.client.run(_worker_threads, on_error="ignore")
            self._record(sum(slots.values()), max(shares.values(), default=1))
            futures = [self.client.submit(_on_worker, func, *args, pure=False)
                       for args in argsets]
            for _ in distributed.as_completed(futures):
                finished()
            return self.client.gather(futures)
        import dask
        from dask.callbacks import Callback

        class Tiles(Callback):
            def _posttask(self, key, value, dsk, state, worker_id):
                finished()

        at_once = 1 if self.name == "sync" else max(1, min(total, self.n_jobs))
        per_task = max(1, self.n_jobs // at_once)
        self._record(at_once, per_task)
        tasks = [dask.delayed(func, pure=False)(*args, per_task) for args in argsets]
        with Tiles():
            return list(dask.compute(*tasks, scheduler=self.name, num_workers=at_once))


def _worker_threads(dask_worker=None):
    """The threads of each task on a Dask worker (this task's, or ``dask_worker``, as
    ``Client.run`` passes it): the cores its process may use, shared between the tasks it runs
    at once (its ``nthreads``)."""
    if dask_worker is None:
        import distributed

        dask_worker = distributed.get_worker()
    cores = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
             else os.cpu_count() or 1)
    return max(1, cores // max(1, dask_worker.state.nthreads))


def _on_worker(func, *args):
    """``func(*args, n_jobs)`` with the worker's share of threads."""
    return func(*args, _worker_threads())
