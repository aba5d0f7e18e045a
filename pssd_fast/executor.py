"""The one executor of the default method: its steps run over tiles with halos, in memory or
from files, and a run in one tile is the in-core run (docs/ALGORITHM.md, "Tiles").

Every step reads a radius the plan fixed before the run (:class:`pssd_fast.plan.Plan`): a
tile's task gets its own items first, then every other item within ``hops`` radii of the
boxes of its own (:mod:`pssd_fast.tiled.tiles`), with their places in the whole cloud, which
order tied neighbours. The lists of the items it keeps are then the whole cloud's, and so are
its results, bit for bit, whatever the tiles (:func:`pssd_fast.graph.nearest_within`).

Steps, each a round of tasks: the cells (each tile holds whole cells, consecutive along
their Morton curve); the iterations on the cell means (four radii of halo in the first, whose
normals are shifted, three after); every point onto the last fits of its nearest means (one
radius); the chi-square test of each cell (one radius); the failing points' own iterations
(four radii of their lists, then three).
"""
import time
from typing import NamedTuple

import numpy as np

from . import core, method
from . import regions as geometry
from ._threads import threads
from .graph import bounded_graph, knn_graph
from .pipelines import aware
from .progress import Clock
from .run import Iterated

#: Tiles start at multiples of this many cells.
ALIGN = 64


class Tile(NamedTuple):
    """A tile: the cells ``c0 .. c1 - 1`` and their points, ``rows`` (indices into the points
    in Morton order, grouped by cell as :func:`pssd_fast.method.cells_of` groups them)."""

    c0: int
    c1: int
    rows: np.ndarray


def tiles_of(cells, tile_points):
    """The tiles of ``cells``: runs of consecutive cells of at most ``tile_points`` points
    (one cell at least), each starting at a multiple of :data:`ALIGN` cells where it can."""
    ends = np.concatenate(([0], np.cumsum(cells.counts)))
    m = cells.counts.shape[0]
    out = []
    c0 = 0
    while c0 < m:
        c1 = int(np.searchsorted(ends, ends[c0] + tile_points, side="right")) - 1
        c1 = max(c1, c0 + 1)
        if c1 < m and c1 - c0 > ALIGN:
            c1 -= (c1 - c0) % ALIGN
        out.append(Tile(c0, c1, cells.order[cells.starts[c0]:cells.starts[c1]]))
        c0 = c1
    return out


class Local:
    """Runs a step's tasks here, one after another, with every thread: the in-core run and
    the tiled runs' ``"sync"`` use it; :class:`pssd_fast.tiled.scheduler.Runner` runs them on
    Dask."""

    name = "in-core"
    threads = None

    def __init__(self, n_jobs):
        self.n_jobs = n_jobs

    def map(self, stage, iteration, iterations, func, argsets):
        return [func(*args, self.n_jobs) for args in argsets]


def run(current, given, plan, request, runner=None, tile_points=None):
    """The default method on the distinct positions ``current`` (Morton order, relative to
    ``request.centre``; the caller's normals ``given`` in that order, or None), in tiles of at
    most ``tile_points`` points (None: one tile) whose tasks ``runner`` runs (None: here).

    Returns an :class:`~pssd_fast.run.Iterated` (the records are the iterations on the
    means, the last one's times with the points' steps added) and the number of tiles.
    """
    runner = Local(None) if runner is None else runner
    params = request.params
    sigma_n, keep = params["sigma_n"], params["keep_normals"]
    cells = method.cells_of(current, given, plan.edge, plan.low)
    tiles = [Tile(0, cells.counts.shape[0], cells.order)] if tile_points is None else \
        tiles_of(cells, tile_points)
    one = len(tiles) == 1
    m = cells.counts.shape[0]
    mass = cells.counts.astype(np.float64)
    hints = core.outward_hints(cells.points)
    positions = cells.points
    held = np.zeros(m, np.bool_)
    records = []
    for t in range(plan.iterations):
        clock = Clock(request.report, t, plan.iterations)
        own_given = cells.normals is not None and (t == 0 or keep)
        normals = cells.normals if own_given else hints
        first = None if own_given else t == 0
        hops = 4 if first else 3
        args = []
        for tile in tiles:
            rows = geometry.gather(positions, tile.c0, tile.c1, hops * plan.bound, one)
            args.append((positions[rows], mass[rows], normals[rows], first, plan.k, plan.bound,
                         sigma_n, rows, tile.c1 - tile.c0))
        started = time.perf_counter()
        parts = runner.map("tile_iteration", t, plan.iterations, _iteration, args)
        fits = method.Fits(*(np.concatenate(column) for column in zip(*parts)), None)
        clock.times["iteration"] = time.perf_counter() - started
        held |= fits.held
        records.append(method.record(clock.times, fits))
        origins, positions, hints = positions, fits.moved, fits.filtered
    clock = Clock(request.report, plan.iterations - 1, plan.iterations)
    point_parts = runner.map("tile_project", plan.iterations - 1, plan.iterations, _project, [
        (current[tile.rows], *_gathered(origins, fits, tile, current, plan.bound, one))
        for tile in tiles])
    moved, normals, held_points, step2 = _scatter(current.shape[0], tiles, point_parts)
    record = records[-1]
    record["cells"] = m
    if plan.refine is not None:
        sums = method.cell_sums(cells, step2)
        fails = np.concatenate(runner.map("tile_test", plan.iterations - 1, plan.iterations,
                                          _test, [
            (cells.points[rows], sums[rows], cells.counts[rows], rows, tile.c1 - tile.c0,
             plan.noise.sigma, plan.bound)
            for tile in tiles for rows in [geometry.gather(cells.points, tile.c0, tile.c1,
                                                           plan.bound, one)]]))
        flagged = fails[cells.owner]
        record["refined"] = int(flagged.sum())
        if flagged.any():
            moved, normals, held_refined = _refine(current, moved, normals, flagged, given,
                                                   keep, plan, sigma_n, tiles, runner, one)
            held_points |= held_refined
    extra = None
    if request.extras:
        extra = clock.run("extras", extras, origins, fits, cells, plan)
    if request.orient is not None:
        clock.run("orient", orient, moved, normals, request.orient, request.centre,
                  None if one else current.mean(axis=0))
    record["times"].update(clock.times)
    return Iterated(moved, normals, extra, records, held_points), len(tiles)


def _iteration(positions, mass, normals, first, k, bound, sigma_n, ids, n_own, n_jobs):
    """A tile's task of one iteration on the means: :func:`pssd_fast.method.iteration` on its
    own means and halo, the own means' :class:`~pssd_fast.method.Fits` (without lists)."""
    with threads(n_jobs):
        fits = method.iteration(positions, mass, k, bound, sigma_n, normals,
                                Clock(None, 0, 1), first, ids)
    return tuple(column[:n_own] for column in fits[:-1])


def _gathered(origins, fits, tile, current, bound, one):
    """What a tile's projection reads: every mean within ``bound`` of its points (their
    origins, filtered normals and fits) and their places, and the bound."""
    rows = geometry.around(origins, current[tile.rows], bound, one)
    return origins[rows], fits.filtered[rows], fits.coef[rows], rows, bound


def _project(points, origins, filtered, coef, ids, bound, n_jobs):
    """A tile's task of the projection: its points moved onto the fits of their nearest
    means, their normals, held mask and squared step."""
    with threads(n_jobs):
        moved, normals, held = method.project(points, origins, method.Fits(
            None, filtered, coef, None, None, None, None), bound, ids)
    step = moved - points
    return moved, normals, held, np.einsum("ij,ij->i", step, step)


def _scatter(n, tiles, parts):
    """The tiles' per-point outputs put back in the points' order."""
    out = None
    for tile, part in zip(tiles, parts):
        if out is None:
            out = [np.empty((n,) + column.shape[1:], column.dtype) for column in part]
        for array, column in zip(out, part):
            array[tile.rows] = column
    return out


def _test(means, sums, counts, ids, n_own, sigma, bound, n_jobs):
    """A tile's task of the chi-square test: whether each of its own cells fails it."""
    with threads(n_jobs):
        return method.failing(means, sums, counts, sigma, bound, ids)[:n_own]


def _refine(current, moved, normals, flagged, given, keep, plan, sigma_n, tiles, runner, one):
    """The failing points' own iterations, tile by tile: every point's position and normal,
    and the flagged points held in some iteration."""
    k, bound = plan.refine
    positions = moved.copy()
    positions[flagged] = current[flagged]
    held = np.zeros(current.shape[0], np.bool_)
    for t in range(method.REFINE["iterations"]):
        use_given = given is not None and (t == 0 or keep)
        hops = 3 if use_given or t > 0 else 4
        args = []
        for tile in tiles:
            rows = geometry.around(positions, positions[tile.rows], hops * bound, one,
                                   own=tile.rows)
            args.append((positions[rows], normals[rows], flagged[rows],
                         given[rows] if use_given else None, rows, tile.rows.shape[0], k,
                         bound, sigma_n, t == 0))
        parts = runner.map("tile_refine", t, method.REFINE["iterations"], _refine_task, args)
        positions, normals, held_now = _scatter(current.shape[0], tiles, parts)
        held |= held_now
    return positions, normals, held


def _refine_task(positions, normals, flagged, given, ids, n_own, k, bound, sigma_n, first,
                 n_jobs):
    """A tile's task of one refining iteration: its own points' positions, normals and held
    mask (:func:`pssd_fast.method.refine_step`)."""
    with threads(n_jobs):
        out, out_normals, held = method.refine_step(positions, normals, flagged, k, bound,
                                                    sigma_n, given, Clock(None, 0, 1), first,
                                                    ids)
    return out[:n_own], out_normals[:n_own], held[:n_own]


def extras(origins, fits, cells, plan):
    """The likelihood and feature intensity of the points: those of their cell's mean (the
    likelihood from the last fits' RMS residual, the ``"exp"`` form; the feature intensity by
    the paper's voting at the paper's constants over the means, at the last iteration's
    start)."""
    lists = bounded_graph(origins, plan.k, plan.bound)
    lik, _ = core.sampling_likelihood(fits.rms, "exp")
    feat = aware.voted_feature(origins, fits.filtered, lists,
                               aware.region_radius(core.mean_spacing(lists)))
    return lik[cells.owner], feat[cells.owner]


def orient(points, normals, how, centre, centroid):
    """``normals`` (in place) turned ``how`` (``"outward"``, ``"up"`` or a viewpoint, given
    absolute): in a run of one tile (``centroid`` None), made consistent over the points'
    lists of :data:`pssd_fast.core.ORIENT_NEIGHBOURS` first and each connected component
    turned as a whole; in tiles each normal on its own (outward: away from ``centroid``, the
    input's), since the propagation runs over the whole cloud."""
    target = how if isinstance(how, str) else how - centre
    if centroid is None:
        lists = knn_graph(points, min(core.ORIENT_NEIGHBOURS, points.shape[0] - 1), False)
        core.orient_normals(points, normals, lists, target)
    else:
        core.orient_pointwise(points, normals, target, centroid)
