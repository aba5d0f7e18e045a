"""The steps of the default method (presets "default" and "fast"; docs/ALGORITHM.md, "The
default method").

One probe gives the noise ``sigma`` and the spacing ``s`` (:mod:`pssd_fast.noise`). The points
are averaged over the cells of a grid of edge ``max(CELL["spacing"] s, CELL["noise"] sigma)``:
where the noise is below the spacing a cell holds about one point and the cells are the points;
where it spans several spacings the cells average it down. The feature-aware fit iterates on the
cell means, each fitted over the means within ``RADIUS`` noise widths (at least ``LIST[0]`` of
them, at most ``LIST[1]``); every point then moves onto the last fits of its nearest means. The
points whose neighbourhood the surface fails to explain within the noise (a chi-square test on
their residuals, ``TEST``) fit their own lists from their input positions (``REFINE``).

Each step reads the items within a radius that the plan fixes before it runs
(:class:`pssd_fast.plan.Plan`): a run in tiles gives every tile a halo of that radius and gets
the whole cloud's result (:mod:`pssd_fast.executor`).
"""
import math
from typing import NamedTuple, Optional

import numpy as np

from . import core
from .graph import bounded_graph, grid_codes, nearest_within
from .pipelines import aware
from .pipelines.normals import estimated_normals
from .progress import Clock

#: The cell edge: the larger of ``spacing`` point spacings and ``noise`` noise widths.
CELL = {"spacing": 0.7, "noise": 1.5}
#: A fit's list reaches this many noise widths.
RADIUS = 8.0
#: The fewest and the most means (or points) in a fit's list.
LIST = (40, 160)
#: Iterations of the fit on the cell means.
ITERATIONS = 2
#: The chi-square test: a neighbourhood fails where its residuals' mean square exceeds
#: ``sigma^2 (1 + TEST sqrt(2 / m))``, ``m`` the points it holds.
TEST = 3.0
#: The failing points' own fits: their lists reach ``radius`` noise widths (at least ``k``
#: points), and they iterate ``iterations`` times.
REFINE = {"radius": 4.0, "k": 24, "iterations": 2}
#: Cells in the chi-square test's neighbourhood of a cell (the cell itself first).
TEST_CELLS = 8
#: Nearest means whose fits a point moves onto (docs/DECISIONS.md, "Scan sizes").
BLEND = 3
#: How far a list may reach, in radii of a list of its length on a uniform sample: lists in
#: sparse regions are cut there rather than reaching across gaps.
REACH = 2.0


class Cells(NamedTuple):
    """The means of the occupied cells, in the Morton order of their cells.

    Attributes
    ----------
    points : (m, 3) float64
    normals : (m, 3) float64 or None
        The unit mean of the given normals of each cell's points.
    counts : (m,) int64
        Points each cell holds.
    order, starts : int64 arrays
        Cell ``c`` holds the points ``order[starts[c]:starts[c + 1]]``.
    """

    points: np.ndarray
    normals: Optional[np.ndarray]
    counts: np.ndarray
    order: np.ndarray
    starts: np.ndarray


def list_length(sigma, spacing, edge, radius=None, shortest=None):
    """The means a fit reads: those within ``radius`` (default ``RADIUS``) noise widths, on a
    surface ``pi R^2`` over the area a mean covers (a cell's, or a point's where the cells are
    smaller than the spacing), held within ``shortest`` (default ``LIST[0]``) and
    ``LIST[1]``."""
    radius = RADIUS if radius is None else radius
    shortest = LIST[0] if shortest is None else shortest
    area = max(spacing, edge) ** 2
    k = math.pi * (radius * sigma) ** 2 / area if area > 0.0 else shortest
    return int(max(shortest, min(LIST[1], round(k))))


def list_bound(k, spacing, edge):
    """The farthest a list of ``k`` means may reach: ``REACH`` times the radius of ``k`` means
    on a surface sampled evenly at the cells' density."""
    return REACH * math.sqrt(k / math.pi) * max(spacing, edge)


def cell_edge(sigma, spacing):
    """The edge of the cells (:data:`CELL`)."""
    return max(CELL["spacing"] * spacing, CELL["noise"] * sigma)


def cells_of(points, normals, edge, low):
    """The :class:`Cells` of ``points`` (Morton order) on the grid of ``edge`` from ``low``."""
    codes = grid_codes(points, low, 1.0 / edge)
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    starts = np.flatnonzero(np.concatenate(([True], codes[1:] != codes[:-1])))
    starts = np.concatenate((starts, [codes.shape[0]])).astype(np.int64)
    means, mean_normals = core.cell_means(points, normals, order, starts)
    return Cells(means, mean_normals, np.diff(starts), order, starts)


class Iterated(NamedTuple):
    """The cell means after the iterations, and the last iteration's fits: ``origins`` (where
    the means were at its start), their ``lists``, ``normals`` (their filtered normals),
    ``coef`` (the fits of :func:`pssd_fast.core.surface_fits`, ``(m, 7)``), ``rms`` and
    ``degree``; the means ``held`` in some iteration; one record per iteration."""

    points: np.ndarray
    origins: np.ndarray
    lists: object
    normals: np.ndarray
    coef: np.ndarray
    rms: np.ndarray
    degree: np.ndarray
    held: np.ndarray
    records: list


def iterate(cells, k, bound, iterations, sigma_n, given, keep_normals, report=None):
    """The feature-aware iterations on the cell means, each fitted over its ``k`` nearest means
    within ``bound``, weighted by the points they hold; the last iteration keeps its fits.

    ``given``: the means' normals from the caller's (the first iteration's; every one's with
    ``keep_normals``), else None: PCA normals, shifted in the first iteration.
    """
    current = cells.points
    mass = cells.counts.astype(np.float64)
    previous = None
    held = np.zeros(current.shape[0], np.bool_)
    records = []
    for iteration in range(iterations):
        clock = Clock(report, iteration, iterations)
        lists = clock.run("neighbors", bounded_graph, current, k, bound)
        if given is not None and (iteration == 0 or keep_normals):
            nrm = given
        else:
            nrm, _ = clock.run("normals", estimated_normals, current, lists, previous, None,
                               np.zeros(3), k if previous is None else None)
        filtered = clock.run("filter", core.filter_normals, current, nrm, lists)
        coef, rms, degree = clock.run("mls", core.surface_fits, current, filtered, lists,
                                      sigma_n, mass)
        moved, held_now = clock.run("update", core.project, current, filtered, coef[:, 0],
                                    lists.radius)
        held |= held_now
        records.append(aware.step_record(clock.times, held_now.sum(), rms.sum(), rms.shape[0],
                                         np.bincount(degree, minlength=7)))
        origins, current, previous = current, moved, filtered
    return Iterated(current, origins, lists, previous, coef, rms, degree, held, records)


def project(points, done, bound):
    """Each point moved onto the fits of its :data:`BLEND` nearest means (their positions at
    the last iteration's start, within ``bound``), by the inverse-distance mean of its steps
    along their normals (:func:`pssd_fast.core.evaluate_fits`); its normal is its nearest
    mean's. Returns the moved points, their normals, the points held (no fit within its
    support) and each point's nearest mean."""
    nearest, distance, _ = nearest_within(done.origins, points,
                                          min(BLEND, done.origins.shape[0]), bound)
    moved, held = core.evaluate_fits(points, done.origins, done.normals, done.coef, nearest,
                                     distance)
    return moved, done.normals[nearest[:, 0]], held, nearest[:, 0]


def failing(cells, residual2, sigma, bound):
    """The cells whose neighbourhood fails the chi-square test (:data:`TEST`): the mean square
    residual of the points of the cell and its ``TEST_CELLS - 1`` nearest cells within
    ``bound``, against ``sigma^2``. ``residual2``: each point's squared step onto the surface,
    in the order of the points."""
    sums = np.add.reduceat(residual2[cells.order], cells.starts[:-1])
    lists = bounded_graph(cells.points, TEST_CELLS, bound)
    total = np.add.reduceat(sums[lists.indices], lists.indptr[:-1])
    points = np.add.reduceat(cells.counts[lists.indices], lists.indptr[:-1]).astype(np.float64)
    noise2 = max(sigma * sigma, np.finfo(np.float64).tiny)
    return total / np.maximum(points, 1.0) > noise2 * (1.0 + TEST * np.sqrt(
        2.0 / np.maximum(points, 1.0)))


def refine(start, normals, flagged, k, bound, sigma_n, given, keep_normals, clock):
    """The flagged points' own feature-aware iterations (:data:`REFINE`), from ``start`` (the
    flagged points' input positions, every other point where the surface put it), each over
    its ``k`` nearest points within ``bound``; the other points lend their positions and
    ``normals``. Returns the flagged points' positions, filtered normals and held mask; the
    stages are timed on ``clock`` (``refine_*``, summed over the iterations)."""
    rows = np.flatnonzero(flagged)
    current = start.copy()
    normals = normals.copy()
    held = np.zeros(rows.shape[0], np.bool_)
    for iteration in range(REFINE["iterations"]):
        lists = clock.run("refine_neighbors", bounded_graph, current, k, bound, rows)
        if given is not None and (iteration == 0 or keep_normals):
            nrm = given.copy()
        else:
            nrm, _ = clock.run("refine_normals", estimated_normals, current, lists, normals,
                               None, np.zeros(3), k if iteration == 0 else None)
        nrm[~flagged] = normals[~flagged]
        moved, filtered, _, _, held_now = clock.run(
            "refine_fit", aware.fit_and_move, current, nrm, lists, sigma_n,
            Clock(None, iteration, REFINE["iterations"]))
        current[rows] = moved[rows]
        normals[rows] = filtered[rows]
        held |= held_now[rows]
    return current[rows], normals[rows], held
