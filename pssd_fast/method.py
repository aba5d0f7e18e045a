"""The steps of the default method (presets "default" and "fast"; docs/ALGORITHM.md, "The
default method").

One probe gives the noise ``sigma`` and the spacing ``s`` (:mod:`pssd_fast.noise`). The points
are averaged over the cells of a grid of edge ``max(CELL["spacing"] s, CELL["noise"] sigma)``:
where the noise is below the spacing a cell holds about one point and the cells are the points;
where it spans several spacings the cells average it down. The feature-aware fit iterates on the
cell means, each fitted over the means within ``RADIUS`` noise widths (at least
``LIST["shortest"]`` of them, at most ``LIST["longest"]``); every point then moves onto the
last fits of its nearest means. The points whose neighbourhood the surface fails to explain
within the noise (a test of their steps against the probe's noise and their own fits'
residuals, ``TEST``) fit their own lists from
their input positions (``REFINE``).

Each step reads the items within a radius that the plan fixes before it runs
(:class:`pssd_fast.plan.Plan`): a run in tiles gives every tile a halo of that radius and gets
the whole cloud's result (:mod:`pssd_fast.executor`).
"""
import math
from typing import NamedTuple, Optional

import numpy as np

from . import core
from .graph import bounded_graph, cell_keys, cell_order, nearest_within
from .pipelines import aware
from .pipelines.normals import pca, shifted
from .progress import Clock

#: The cell edge: the larger of ``spacing`` point spacings and ``noise`` noise widths.
CELL = {"spacing": 0.7, "noise": 1.5}
#: A fit's list reaches this many noise widths, counting one mean per cell of the surface
#: (where the cells slice the noise, a column holds several and the lists reach about 5;
#: docs/ALGORITHM.md, "Known behaviour of the default method").
RADIUS = 8.0
#: The fewest and the most means (or points) in a fit's list, and how far a list may reach
#: (``reach``), in radii of a list of its length on a uniform sample: lists in sparse regions
#: are cut there rather than reaching across gaps.
LIST = {"shortest": 80, "longest": 160, "reach": 2.0}
#: Iterations of the fit on the cell means.
ITERATIONS = 2
#: The test of the fits (docs/ALGORITHM.md, "The test and the refinement"): a neighbourhood
#: (a cell and its ``cells - 1`` nearest cells, ``m`` points) fails where its points' squared
#: steps onto the fits add up to more than the probe's noise by ``z`` standard deviations of a
#: chi-square of ``m`` degrees (``sqrt(2 / m)`` relative); or, where the points' own fits have
#: lists spanning at least ``span`` noise widths, more than the points' own noise (their
#: squared residuals about their own fits, over ``reads``: what those read of a noisy plane's
#: variance) by ``z_own`` standard deviations of the ratio of two such chi-squares
#: (``sqrt(4 / m)``), plus what their own fits would leave of it.
TEST = {"z": 1.0, "cells": 32, "span": 3.0, "reads": 0.91, "z_own": 4.0}
#: Where the refinement's lists span fewer than ``TEST["span"]`` of the probe's noise widths
#: but at least this share of them, the own fits' reading decides whether they span as many
#: of the noise the own fits read (:func:`own_reading_decides`; docs/ALGORITHM.md, "The test
#: and the refinement").
OWN_READ = 0.5
#: The failing points' own fits: their lists reach ``radius`` noise widths (at least ``k``
#: points), and they iterate ``iterations`` times.
REFINE = {"radius": 4.0, "k": 40, "iterations": 2}
#: Lists the test sums at a time.
SUM_BLOCK = 1 << 16
#: Nearest means whose fits a point moves onto (docs/DECISIONS.md, "Scan sizes: one fit per
#: surface point").
BLEND = 3


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
    owner : (n,) int64
        The cell of each point.
    """

    points: np.ndarray
    normals: Optional[np.ndarray]
    counts: np.ndarray
    order: np.ndarray
    starts: np.ndarray
    owner: np.ndarray


def list_length(sigma, spacing, edge, radius=None, shortest=None):
    """The means a fit reads: those within ``radius`` (default ``RADIUS``) noise widths, on a
    surface ``pi R^2`` over the area a mean covers (a cell's, or a point's where the cells are
    smaller than the spacing), held within ``shortest`` (default ``LIST["shortest"]``)
    and ``LIST["longest"]``."""
    radius = RADIUS if radius is None else radius
    shortest = LIST["shortest"] if shortest is None else shortest
    area = max(spacing, edge) ** 2
    k = math.pi * (radius * sigma) ** 2 / area if area > 0.0 else shortest
    return int(max(shortest, min(LIST["longest"], round(k))))


def list_bound(k, spacing, edge):
    """The farthest a list of ``k`` means may reach: ``LIST["reach"]`` times the radius of
    ``k`` means on a surface sampled evenly at the cells' density."""
    return LIST["reach"] * math.sqrt(k / math.pi) * max(spacing, edge)


def list_radius(k, spacing):
    """The radius of a list of ``k`` points on an even sample of ``spacing``: ``sqrt(k / pi)``
    spacings."""
    return math.sqrt(k / math.pi) * spacing


def own_lists_span(k, spacing, sigma):
    """Whether lists of ``k`` points (:func:`list_radius`) span ``TEST["span"]`` noise widths:
    the least at which a fit's residuals read the noise rather than a part of it (a narrower
    list holds the points nearest the point's own height; docs/ALGORITHM.md, "The test and the
    refinement")."""
    return list_radius(k, spacing) >= TEST["span"] * sigma


def own_reading_decides(k, spacing, sigma):
    """Whether the own fits' reading of the noise decides :func:`own_lists_span` for lists of
    ``k`` points where the probe's noise ``sigma`` does not: they span fewer than
    ``TEST["span"]`` noise widths of it but at least :data:`OWN_READ` of that. Narrower,
    they are narrower than the noise itself can be (the probe over-reads a noise at most
    2.06 times on the clouds measured), and the reading cannot tell them from lists of 3
    noise widths: a list far narrower than the noise is a ball in it, whose own fit reads a
    quarter of its radius, as a list of 3.7 noise widths does."""
    return (not own_lists_span(k, spacing, sigma)
            and list_radius(k, spacing) >= OWN_READ * TEST["span"] * sigma)


def cell_edge(sigma, spacing):
    """The edge of the cells (:data:`CELL`)."""
    return max(CELL["spacing"] * spacing, CELL["noise"] * sigma)


def cells_of(points, normals, edge, low):
    """The :class:`Cells` of ``points`` (Morton order) on the grid of ``edge`` from ``low``,
    in the Morton order of the cells (:func:`pssd_fast.graph.cell_keys`)."""
    order, starts = cell_order(*cell_keys(points, low, edge))
    means, mean_normals = core.cell_means(points, normals, order, starts)
    counts = np.diff(starts)
    owner = np.empty(points.shape[0], np.int64)
    owner[order] = np.repeat(np.arange(counts.shape[0]), counts)
    return Cells(means, mean_normals, counts, order, starts, owner)


class Fits(NamedTuple):
    """One iteration's outputs on the means (or a tile's own means): the ``moved`` means, the
    ``filtered`` normals, the fits ``coef`` (:func:`pssd_fast.core.surface_fits`, ``(m, 7)``),
    their ``rms`` residual and ``degree``, the means ``held`` in place and the ``lists``."""

    moved: np.ndarray
    filtered: np.ndarray
    coef: np.ndarray
    rms: np.ndarray
    degree: np.ndarray
    held: np.ndarray
    lists: object


def iteration(current, mass, k, bound, sigma_n, normals, clock, first, ids=None, shift=True):
    """One feature-aware iteration on the cell means ``current`` (weighted by the points they
    hold, ``mass``), each fitted over its ``k`` nearest means within ``bound`` (ties ordered by
    ``ids``, the means' places in the whole cloud, where given): a :class:`Fits`.

    ``normals``: the caller's (given) normals, or the hints that sign the PCA normals (the
    previous iteration's filtered normals, or the directions away from the centroid of the
    whole cloud); ``first``: whether they are hints of the first iteration, whose normals are
    shifted where ``shift`` (docs/ALGORITHM.md, "Shifted normals"); None when ``normals`` are
    given. Its steps, each reading the lists' members' results of the one before, are
    :func:`listed`, :func:`pca_step`, :func:`shift_step`, the filter and :func:`fit_step`,
    which tiles run as rounds of their own (:mod:`pssd_fast.executor`).
    """
    lists = listed(current, k, bound, ids, clock)
    nrm, planes = pca_step(current, lists, normals, first, shift, clock)
    if planes is not None:
        nrm = shift_step(current, nrm, lists, planes, k, clock)
    filtered = clock.run("filter", core.filter_normals, current, nrm, lists)
    return fit_step(current, mass, filtered, lists, sigma_n, clock)


def listed(current, k, bound, ids, clock, own=None):
    """The lists of :func:`iteration` (of the first ``own`` means only, where given)."""
    return clock.run("neighbors", bounded_graph, current, k, bound, None, ids, own)


def pca_step(current, lists, normals, first, shift, clock):
    """The normals :func:`iteration` filters, and the lists' planes where the first
    iteration shifts them next (else None)."""
    if first is None:
        return normals, None
    nrm, _, planes = clock.run("normals", pca, current, lists, normals, bool(first and shift))
    return nrm, planes


def shift_step(current, nrm, lists, planes, k, clock):
    """The first iteration's shifted normals, from the ``planes`` of the lists' members."""
    return clock.run("normals", shifted, current, nrm, lists, planes, k)


def fit_step(current, mass, filtered, lists, sigma_n, clock):
    """The fits over the lists with the ``filtered`` normals and each mean's move onto its
    own: the :class:`Fits` of :func:`iteration`."""
    coef, rms, degree = clock.run("mls", core.surface_fits, current, filtered, lists, sigma_n,
                                  mass)
    moved, held = clock.run("update", core.project, current, filtered, coef[:, 0],
                            lists.radius)
    return Fits(moved, filtered, coef, rms, degree, held, lists)


def _normals(points, lists, hints, shift_k):
    """PCA normals signed along ``hints``, shifted where ``shift_k`` is given."""
    nrm, _, planes = pca(points, lists, hints, shift_k is not None)
    return nrm if shift_k is None else shifted(points, nrm, lists, planes, shift_k)


def project(points, origins, fits, bound, ids=None):
    """Each point moved onto the fits of its :data:`BLEND` nearest means (``origins``, their
    positions at the last iteration's start, within ``bound``; ties ordered by ``ids`` where
    given), by the inverse-distance mean of its steps along their normals
    (:func:`pssd_fast.core.evaluate_fits`); its normal is its nearest mean's. Returns the moved
    points, their normals and the points held (no fit within its support)."""
    nearest, distance, counts = nearest_within(origins, points, min(BLEND, origins.shape[0]),
                                               bound, ids)
    moved, held = core.evaluate_fits(points, origins, fits.filtered, fits.coef, nearest,
                                     distance)
    first = nearest[:, 0]
    normals = fits.filtered[np.minimum(first, origins.shape[0] - 1)]
    normals[counts == 0] = np.nan
    return moved, normals, held


def failing(means, sums, counts, sigma, bound, ids=None, own=None, first=None):
    """Which cells' neighbourhoods fail the test (:data:`TEST`): over the points of the cell
    and its ``TEST["cells"] - 1`` nearest cells within ``bound`` (``means``: the cells' input
    means; ``counts``: their points; ``m`` the points in all), the sum of the points' squared
    steps onto the fits (``sums``, per cell) above ``m sigma^2 (1 + z sqrt(2 / m))``; or, where
    ``own`` gives per cell the points' own noise variances and what their own fits would leave
    of them (:func:`own_noise`), above the sum of the first times ``1 + z_own sqrt(4 / m)``
    plus the sum of the second: the fits' bias against what each point's own fit would
    cost. Of the ``first`` cells only where given (the others' results are meaningless)."""
    lists = bounded_graph(means, TEST["cells"], bound, None, ids, first)
    n = means.shape[0]

    def summed(values):
        # Block by block: the values of every list at once take 8 bytes an entry.
        out = np.empty(n)
        for start in range(0, n, SUM_BLOCK):
            stop = min(n, start + SUM_BLOCK)
            first, last = lists.indptr[start], lists.indptr[stop]
            out[start:stop] = np.add.reduceat(values[lists.indices[first:last]],
                                              lists.indptr[start:stop] - first)
        return out

    total, points = summed(sums), np.maximum(summed(counts.astype(np.float64)), 1.0)
    sigma2 = max(sigma * sigma, np.finfo(np.float64).tiny)
    fails = total > points * sigma2 * (1.0 + TEST["z"] * np.sqrt(2.0 / points))
    if own is not None:
        noise2, spread2 = (summed(values) for values in own)
        fails |= total > spread2 + noise2 * (1.0 + TEST["z_own"] * np.sqrt(4.0 / points))
    return fails


def own_noise(points, hints, k, bound, sigma_n, ids=None):
    """Each point's noise as its own fit sees it, and the variance that fit leaves: its
    squared residual about the feature-aware quadratic (robust alternative included) of its
    ``k`` nearest points within ``bound`` (ties ordered by ``ids``), PCA normals signed along
    ``hints`` (where not finite: away from the centre), over ``1 - H``, ``H`` the plain fit's
    leverage on the point; and that times ``H``."""
    lists = bounded_graph(points, k, bound, None, ids)
    signs = np.where(np.isfinite(hints).all(axis=1)[:, None], hints, points)
    filtered = core.filter_normals(points, _normals(points, lists, signs, None), lists)
    height, _, _, leverage = core.own_fits(points, filtered, lists, sigma_n)
    noise2 = height * height / (TEST["reads"] * np.maximum(1.0 - leverage,
                                                           np.finfo(np.float64).eps))
    return noise2, noise2 * leverage


def refine_step(current, normals, flagged, k, bound, sigma_n, given, clock, first, ids=None,
                shift=True):
    """One of the flagged points' own feature-aware iterations (:data:`REFINE`): each flagged
    point fitted over its ``k`` nearest points within ``bound`` (ties ordered by ``ids`` where
    given), the others lending their positions and ``normals``. ``given``: the flagged points'
    normals from the caller's, else None (PCA signed like ``normals``, shifted where ``first``
    and ``shift``). Returns every point's position and normal after it, and the flagged
    points held in place."""
    rows = np.flatnonzero(flagged)
    lists = clock.run("refine_neighbors", bounded_graph, current, k, bound, rows, ids)
    if given is not None:
        nrm = given.copy()
    else:
        nrm = clock.run("refine_normals", _normals, current, lists, normals,
                        k if first and shift else None)
    # Few points are flagged: one pass, not a masked copy of every other row.
    nrm = np.where(flagged[:, None], nrm, normals)
    moved, filtered, _, _, held = clock.run("refine_fit", aware.fit_and_move, current, nrm,
                                            lists, sigma_n, Clock(None, 0, 1))
    out = current.copy()
    out[rows] = moved[rows]
    out_normals = normals.copy()
    out_normals[rows] = filtered[rows]
    return out, out_normals, held & flagged
