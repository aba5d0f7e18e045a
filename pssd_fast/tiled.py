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

import numpy as np

from . import ondisk
from ._threads import threads
from ._validation import (
    as_normals, as_points, check_choice, check_float, check_int, check_orient, check_size,
)
from .denoise import PRESETS, iterate, result
from .graph import bounds, morton_order
from .kernels.order import gather_rows
from .pipelines import STEPS, aware, coarse
from .progress import Clock, reporter

#: Dask's local schedulers, by the names ``client`` takes for them.
LOCAL_SCHEDULERS = ("threads", "processes", "sync")
#: What :func:`denoise_file` reads and writes, by extension.
FILE_KINDS = {".npy": "npy", ".las": "las", ".laz": "las"}
#: The feature-aware pipeline's parameters other than ``sigma_n``, at their defaults.
PARAMS = {"keep_normals": False}


def denoise(points, normals=None, *, tile_points=2_000_000, client=None, preset="default",
            iterations=None, orient=None, sigma_n=0.05, n_jobs=None, progress=None):
    """Denoise ``points`` tile by tile on Dask; the result of :func:`pssd_fast.denoise`.

    Parameters
    ----------
    points : (n, 3) array_like
    normals : (n, 3) array_like, optional
        As in :func:`pssd_fast.denoise`.
    tile_points : int
        The most points a tile holds (a tile is never smaller than one grid cell).
    client : None, str or distributed.Client
        Where the tile tasks run: None or ``"threads"`` (Dask's local threads),
        ``"processes"`` or ``"sync"`` (Dask's local process pool, or this thread), a
        ``distributed.Client``, or the address of a Dask scheduler.
    preset : {"default", "fast"}
        The preset of :func:`pssd_fast.denoise`; its coarse-to-fine route is the one that
        tiles.
    iterations, orient, sigma_n, n_jobs, progress
        As in :func:`pssd_fast.denoise`; ``n_jobs`` threads run each task's kernels and
        ``progress`` also hears of each finished tile (stages ``tile_cells`` and
        ``tile_update``).

    Returns
    -------
    DenoiseResult
        Bit-identical to ``pssd_fast.denoise(points, normals, preset=preset, ...)``;
        ``stats["tiles"]`` gives the number of tiles, their most points and the scheduler.

    Raises
    ------
    ValueError
        Where the in-core run would not take the coarse-to-fine route (the noise is small
        against the point spacing, see docs/ALGORITHM.md): such a cloud is iterated on its
        points, which does not tile without halos; ``pssd_fast.denoise`` runs it.
    ImportError
        Without Dask.
    """
    setting, tile_points, sigma_n, iterations = _settings(preset, tile_points, sigma_n,
                                                          iterations, client)
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
    started = time.perf_counter()
    order = morton_order(pts)
    centre = 0.5 * np.add(*bounds(pts))
    current = np.empty_like(pts)
    gather_rows(pts, order, centre, current)
    given = None if given is None else given[order]
    params = {**PARAMS, "sigma_n": sigma_n}
    with threads(n_jobs) as n_threads, _Runner(client, n_threads, report) as runner:
        k, scale, _ = aware.choose_k(current, given, *setting["probe"])
        found = sigma = None
        if scale["ratio"] >= coarse.COARSE[preset]["min_ratio"]:
            sigma = aware.noise_sigma(current, given, scale)
            found = coarse.layout(current, sigma, preset)
        _check_found(found, preset, scale)
        rows, starts, edge, k, rebuild_graph = found
        tiles = _tiles(starts, tile_points)
        parts = [rows[starts[c0]:starts[c1]] for c0, c1 in tiles]
        sums = runner.map("tile_cells", 1, iterations, _tile_cells, [
            (current[part], None if given is None else given[part],
             starts[c0:c1 + 1] - starts[c0]) for part, (c0, c1) in zip(parts, tiles)])
        cells = coarse.Cells(np.concatenate([s[0] for s in sums]),
                             None if given is None else np.concatenate([s[1] for s in sums]),
                             np.diff(starts), edge, k, coarse.COARSE[preset]["surface_k"],
                             rebuild_graph)
        means, out_normals, extra, records = iterate(
            cells.points, cells.normals, STEPS["aware"], k, iterations, rebuild_graph, None,
            None, params, orient, centre, report, cells.counts)
        surface, surface_normals, extra = coarse.collapse(cells, means, out_normals, extra)
        clock = Clock(report, iterations - 1, iterations)
        coef, rms, degree = coarse.fit_surface(surface, surface_normals, cells.surface_k,
                                               sigma_n, clock)
        moved = runner.map("tile_update", iterations, iterations, _tile_update, [
            (current[part], surface, surface_normals, coef) for part in parts])
    every = np.concatenate(parts)
    current[every] = np.concatenate([m[0] for m in moved])
    held = np.empty(n, np.bool_)
    held[every] = np.concatenate([m[1] for m in moved])
    nearest = np.empty(n, np.int64)
    nearest[every] = np.concatenate([m[2] for m in moved])
    records[-1]["times"].update(clock.times)
    scale["coarse"] = coarse.describe(sigma, edge, cells.counts, surface, cells.surface_k,
                                      coarse.fit_record(held, nearest, rms, degree))
    stats = {
        "method": "robust", "n_points": n, "k": k, "lam": None, "preset": preset,
        "pipeline": "aware", "auto_k": scale, "noise": scale["noise"],
        "rebuild_graph": bool(rebuild_graph),
        "orient": orient if orient is None or isinstance(orient, str) else orient.tolist(),
        "outliers": None, "n_iterations": iterations, "params": params, "n_jobs": n_threads,
        "iterations": records,
        "tiles": {"count": len(tiles), "most_points": int(max(len(p) for p in parts)),
                  "scheduler": runner.name},
        "total_seconds": time.perf_counter() - started,
    }
    return result(pts, dtype, order, centre, current, surface_normals[nearest],
                  tuple(x[nearest] for x in extra), np.arange(n), (pts.astype(dtype), n_jobs),
                  stats)


def denoise_file(source, destination, *, tile_points=2_000_000, client=None, preset="default",
                 iterations=None, sigma_n=0.05, n_jobs=None, progress=None, scratch=None,
                 overwrite=False):
    """Denoise the points of an ``.npy`` or LAS/LAZ file into another, out of core, tile by
    tile on Dask.

    The input is read in chunks; the points are binned into tile files in a scratch folder,
    each task reads one tile, and the output is written in the input's row order. Memory
    follows ``tile_points`` and the number of grid cells (the noise), not the number of points.
    The denoised points are those of :func:`pssd_fast.denoise`, bit for bit.

    Parameters
    ----------
    source : path-like
        An ``.npy`` file of a real ``(n, 3)`` array, or a LAS/LAZ file (its ``nx``, ``ny``,
        ``nz`` dimensions, if any, are not read).
    destination : path-like
        Written only when complete. For ``.npy`` input an ``.npy`` file: the denoised ``(n, 3)``
        points in the input's rows, float32 for float32 input and float64 otherwise. For
        LAS/LAZ input a ``.las``/``.laz`` file: the input with the denoised coordinates
        (quantised as :func:`pssd_fast.io.write` quantises them), every other record byte, the
        header, the VLRs and the EVLRs as read.
    tile_points, client, preset, iterations, sigma_n, n_jobs, progress
        As in :func:`denoise`; progress also hears of the passes over the file (``buckets``,
        ``tiles``) and of the output (``write``).
    scratch : path-like, optional
        Where the scratch folder goes (default: beside ``destination``); with a cluster, a
        folder every worker reads and writes. It is removed on success, on failure and on
        interrupt.
    overwrite : bool
        Replace an existing ``destination``.

    Returns
    -------
    dict
        The run's ``stats``, as :func:`denoise` gives them.

    Raises
    ------
    ValueError
        For a cloud the preset iterates on its points (see :func:`denoise`), bad input, or
        other formats (Zarr is not read yet).
    FileExistsError
        ``destination`` exists and ``overwrite`` is False.
    """
    source, destination = Path(source), Path(destination)
    kinds = {path: FILE_KINDS.get(path.suffix.lower()) for path in (source, destination)}
    if None in kinds.values() or len(set(kinds.values())) > 1:
        raise ValueError(f"denoise_file reads .npy into .npy, or .las/.laz into .las/.laz; got "
                         f"{source.name} and {destination.name} (other formats: "
                         f"pssd_fast.io.read, then denoise)")
    setting, tile_points, sigma_n, iterations = _settings(preset, tile_points, sigma_n,
                                                          iterations, client)
    if destination.exists() and not overwrite:
        raise FileExistsError(f"{destination} exists; pass overwrite=True to replace it")
    if destination.resolve() == source.resolve():
        raise ValueError(f"the output {destination} would overwrite the input")
    array = ondisk.NpyFile(source) if kinds[source] == "npy" else ondisk.LasFile(source)
    dtype = np.dtype(np.float32) if array.dtype == np.float32 else np.dtype(np.float64)
    report = reporter(progress)
    started = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix="pssd_tiles_", dir=scratch or destination.parent))
    # Beside the destination, so that the last rename stays on one file system.
    output = destination.with_name(f".{destination.stem}.{os.getpid()}.partial"
                                   f"{destination.suffix}")
    params = {**PARAMS, "sigma_n": sigma_n}
    try:
        with threads(n_jobs) as n_threads, _Runner(client, n_threads, report) as runner:
            first = Clock(report, 0, iterations)
            cloud = first.run("buckets", ondisk.Buckets, array, folder, tile_points)
            k, scale, _ = aware.choose_k(cloud, None, *setting["probe"])
            found = sigma = None
            if scale["ratio"] >= coarse.COARSE[preset]["min_ratio"]:
                sigma = aware.noise_sigma(cloud, None, scale)
                found = cloud.layout(sigma, preset)
            _check_found(found, preset, scale)
            codes, counts, edge, k, rebuild_graph = found
            starts = np.concatenate(([0], np.cumsum(counts)))
            tiles = _tiles(starts, tile_points)
            paths = first.run("tiles", cloud.tiles, folder,
                              codes[[c0 for c0, _ in tiles]], edge)
            sums = runner.map("tile_cells", 1, iterations, _file_cells,
                              [(path, cloud.centre) for path in paths])
            cells = coarse.Cells(np.concatenate(sums), None, counts, edge, k,
                                 coarse.COARSE[preset]["surface_k"], rebuild_graph)
            means, out_normals, extra, records = iterate(
                cells.points, None, STEPS["aware"], k, iterations, rebuild_graph, None, None,
                params, None, cloud.centre, report, cells.counts)
            surface, surface_normals, extra = coarse.collapse(cells, means, out_normals, extra)
            clock = Clock(report, iterations - 1, iterations)
            coef, rms, degree = coarse.fit_surface(surface, surface_normals, cells.surface_k,
                                                   sigma_n, clock)
            parts = [folder / f"part_{i}.bin" for i in range(len(paths))]
            fits = runner.map("tile_update", iterations, iterations, _file_update, [
                (path, part, cloud.centre, surface, surface_normals, coef, rms, degree)
                for path, part in zip(paths, parts)])
            clock.run("write", _write, array, output, parts, cloud.shape[0], dtype, folder)
            os.replace(output, destination)
        records[0]["times"].update(first.times)
        records[-1]["times"].update(clock.times)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        output.unlink(missing_ok=True)
    n = cloud.shape[0]
    fit = coarse.fit_summary(sum(f[0] for f in fits), sum(f[1] for f in fits),
                             np.sum([f[2] for f in fits], axis=0), n)
    scale["coarse"] = coarse.describe(sigma, edge, counts, surface, cells.surface_k, fit)
    return {
        "method": "robust", "n_points": n, "k": k, "lam": None, "preset": preset,
        "pipeline": "aware", "auto_k": scale, "noise": scale["noise"],
        "rebuild_graph": bool(rebuild_graph), "orient": None, "outliers": None,
        "n_iterations": iterations, "params": params, "n_jobs": n_threads,
        "iterations": records,
        "tiles": {"count": len(tiles),
                  "most_points": int(max(starts[c1] - starts[c0] for c0, c1 in tiles)),
                  "scheduler": runner.name},
        "total_seconds": time.perf_counter() - started,
    }


def _write(array, output, parts, n, dtype, folder):
    """The parts' points in the input's rows: an ``.npy`` array, or a copy of the LAS/LAZ
    input with those coordinates."""
    if isinstance(array, ondisk.NpyFile):
        ondisk.write_rows(output, parts, n, dtype)
        return
    rows = folder / "rows.npy"
    ondisk.write_rows(rows, parts, n, dtype)
    array.write(output, ondisk.NpyFile(rows))


def _settings(preset, tile_points, sigma_n, iterations, client):
    """The arguments both entry points share, checked: the preset's settings, ``tile_points``,
    ``sigma_n`` and the iterations."""
    check_choice(preset, "preset", tuple(coarse.COARSE))
    if not (client is None or isinstance(client, str) or hasattr(client, "submit")):
        raise TypeError(f"client must be None, one of {LOCAL_SCHEDULERS}, a scheduler address "
                        f"or a distributed.Client; got {client!r}")
    setting = PRESETS[preset]
    return (setting, check_int(tile_points, "tile_points", minimum=1),
            check_float(sigma_n, "sigma_n", positive=True),
            check_int(setting["iterations"] if iterations is None else iterations,
                      "iterations", minimum=1))


def _check_found(found, preset, scale):
    """The error for a cloud the preset iterates on its points."""
    if found is None:
        raise ValueError(
            f"preset {preset!r} iterates on the points of this cloud (noise ratio "
            f"{scale['ratio']:.2f}, coarse-to-fine route from "
            f"{coarse.COARSE[preset]['min_ratio']}): it does not tile; run pssd_fast.denoise")


def _file_cells(path, centre, n_jobs):
    """The cell means of a tile file."""
    with threads(n_jobs):
        _, codes, points = ondisk.read_tile(path, centre)
        return coarse.cell_means(points, None, *coarse.group_codes(codes))[0]


def _file_update(path, part, centre, surface, normals, coef, rms, degree, n_jobs):
    """A tile file's points moved onto the fits, saved to ``part`` (rows and coordinates);
    returns the held points, the sum of the nearest fits' residuals and their degrees."""
    with threads(n_jobs):
        rows, _, points = ondisk.read_tile(path, centre)
        moved, held, nearest = coarse.onto_fits(points, surface, normals, coef)
        records = np.empty(rows.shape[0], ondisk.PART)
        records["row"] = rows
        records["xyz"] = moved + centre
        # A task run again after a lost worker finds no half-written part.
        temporary = part.with_suffix(".partial")
        records.tofile(temporary)
        os.replace(temporary, part)
        return (int(held.sum()), float(rms[nearest].sum()),
                np.bincount(degree[nearest], minlength=7))


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
        return coarse.cell_means(points, normals, np.arange(points.shape[0]), starts)


def _tile_update(points, surface, normals, coef, n_jobs):
    """A tile's points moved onto the fits: moved, held, nearest mean."""
    with threads(n_jobs):
        return coarse.onto_fits(points, surface, normals, coef)


class _Runner:
    """Runs each tile's task on the chosen scheduler and reports each finished tile."""

    def __init__(self, client, n_jobs, report):
        self.client = client
        self.n_jobs = n_jobs
        self.report = report
        self.own = None
        self.name = "threads" if client is None else (
            client if client in LOCAL_SCHEDULERS else "distributed")

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

            futures = [self.client.submit(func, *args, self.n_jobs, pure=False)
                       for args in argsets]
            for _ in distributed.as_completed(futures):
                finished()
            return self.client.gather(futures)
        import dask
        from dask.callbacks import Callback

        class Tiles(Callback):
            def _posttask(self, key, value, dsk, state, worker_id):
                finished()

        tasks = [dask.delayed(func, pure=False)(*args, self.n_jobs) for args in argsets]
        with Tiles():
            return list(dask.compute(*tasks, scheduler=self.name))
