"""Coarse to fine: the default on clouds whose noise spans several point spacings
(docs/ALGORITHM.md, "Coarse to fine"; docs/DECISIONS.md, "Scan sizes").

The points are averaged over grid cells whose edge follows the estimated noise, the feature-aware
iterations denoise those cell means (each weighted in the fits by the points it holds), the
denoised means are averaged again over the same grid and each is fitted once, and every input
point then moves onto the fits of its nearest denoised means. The cost of the iterations follows
the noise (the number of cells), not the number of points.
"""
from typing import NamedTuple, Optional

import numpy as np

from .. import core
from .._threads import kdtree
from ..graph import QUERY_ENTRIES, bounds, grid_codes, knn_graph
from ..pipelines.aware import interpolated_k

#: Settings of each preset. ``cell``: cell edge over the noise's standard deviation
#: (:func:`.aware.noise_sigma`); ``k``: neighbours of the iterations on the cell means,
#: interpolated linearly in ``log(points per cell)`` between the anchors
#: ``(points per cell, k)`` and held at the end values outside them; ``surface_k``: cell means
#: in the fit around each denoised mean that the input points are moved onto; ``min_points``:
#: the mean number of points a cell must hold; ``grow``: with fewer, False gives up the cells
#: (the input is iterated on), True widens them until they hold that many; ``min_ratio``: the
#: noise probe's ``sigma / r`` from which the cells are used at all (:func:`.aware.choose_k`;
#: its ``k`` is capped at 160 from 0.304 on); ``rebuild_from``: from this many points per cell
#: on, the cell means' neighbours are queried anew in every iteration (``rebuild_graph="auto"``),
#: else the first iteration's are refreshed. Chosen on the CAD part at 30,000 to 10 million
#: points and 0.25% to 1% noise (docs/DECISIONS.md, "Scan sizes").
COARSE = {
    "default": {"cell": 1.5, "k": ((4.0, 96), (13.0, 128)), "surface_k": 16, "min_points": 3.0,
                "grow": False, "min_ratio": 0.5, "rebuild_from": float("inf")},
    "fast": {"cell": 1.5, "k": ((3.5, 48), (5.0, 70), (13.0, 96)), "surface_k": 16,
             "min_points": 3.0, "grow": True, "min_ratio": 0.0, "rebuild_from": 13.0},
}

_CELL_BITS = 21  # per axis, as the Morton codes of :func:`pssd_fast.graph.morton_order`


class Cells(NamedTuple):
    """The coarse cloud: cell means in Morton order of their cells.

    Attributes
    ----------
    points : (m, 3) float64
    normals : (m, 3) float64 or None
        Mean of the given normals of each cell's points (None without given normals).
    counts : (m,) int64
        Points of each cell.
    edge : float
        Cell edge.
    k : int
        Neighbours of the iterations on the cell means (:data:`COARSE`).
    surface_k : int
        Cell means in the fit around each denoised mean (:func:`refine`).
    rebuild_graph : bool
        Whether the iterations query the cell means' neighbours anew (unless the caller says).
    """

    points: np.ndarray
    normals: Optional[np.ndarray]
    counts: np.ndarray
    edge: float
    k: int
    surface_k: int
    rebuild_graph: bool


#: Rounds of widening (``grow``): each scales the edge by ``sqrt`` of the shortfall, plus 5%.
_GROW_ROUNDS = 8


def cells_of(points, normals, found, preset):
    """The coarse cloud of the ``preset``'s cells ``found`` by :func:`layout`, as
    :class:`Cells`."""
    order, starts, edge, k, rebuild_graph = found
    means, mean_normals = core.cell_means(points, normals, order, starts)
    return Cells(means, mean_normals, np.diff(starts), edge, k, COARSE[preset]["surface_k"],
                 rebuild_graph)


def layout(points, noise, preset):
    """The ``preset``'s cells (:data:`COARSE`), of edge ``cell * noise`` (widened until they
    hold ``min_points`` points on average where ``grow``): ``(order, starts, edge, k,
    rebuild_graph)`` as :func:`group_cells` and :class:`Cells` give them; None when the cells
    hold too few points (and do not grow), when there would be no more cells than the
    iterations' ``k``, or more cells than the grid's codes allow."""
    def group(edge):
        grouped = group_cells(points, edge)
        return None if grouped is None else (grouped[1].shape[0] - 1, grouped)

    found = widen(points.shape[0], noise, preset, group)
    if found is None:
        return None
    (order, starts), edge, k, rebuild_graph = found
    return order, starts, edge, k, rebuild_graph


def widen(n, noise, preset, group):
    """:func:`layout`'s choices for ``n`` points, whatever groups them: ``group(edge)`` gives
    the number of cells of that edge and the grouping, or None where the grid's codes do not
    suffice. Returns ``(grouping, edge, k, rebuild_graph)`` or None."""
    setting = COARSE[preset]
    edge = setting["cell"] * noise
    for _ in range(_GROW_ROUNDS):
        grouped = group(edge)
        if grouped is None:
            return None
        m, grouping = grouped
        if n >= setting["min_points"] * m or not setting["grow"]:
            break
        # Points per cell grow about as the square of the edge on a surface.
        edge *= 1.05 * np.sqrt(setting["min_points"] * m / n)
    k = interpolated_k(n / m, setting["k"])
    if n < setting["min_points"] * m or m <= k:
        return None
    return grouping, edge, k, n >= setting["rebuild_from"] * m


def group_cells(points, edge):
    """The rows of ``points`` grouped by grid cell of edge ``edge``: ``(order, starts)``, cell
    ``c`` holding rows ``order[starts[c]:starts[c + 1]]`` in increasing order, the cells along
    the Morton curve of their grid coordinates; None if the grid needs more than 21 bits an
    axis."""
    low, high = bounds(points)
    codes = cell_codes(points, low, high, edge)
    return None if codes is None else group_codes(codes)


def group_codes(codes):
    """``(order, starts)`` of :func:`group_cells` for the points' cell ``codes``."""
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    starts = np.flatnonzero(np.concatenate(([True], codes[1:] != codes[:-1])))
    return order, np.concatenate((starts, [codes.shape[0]]))


def cell_codes(points, low, high, edge):
    """Morton code of the grid cell of edge ``edge`` (corner ``low``) of each of ``points``;
    None if a grid reaching ``high`` needs more than 21 bits an axis."""
    extent = float((high - low).max())
    if not edge > 0.0 or extent / edge >= 2**_CELL_BITS - 1:
        return None
    return grid_codes(points, low, 1.0 / edge)


def collapse(cells, points, normals, fields):
    """The denoised cell means ``points`` (unit ``normals``, per-point ``fields``) averaged
    again over the grid of ``cells``, each weighted by the points it stands for:
    ``(points, normals, fields)``.

    Where the noise spans several cells across the surface, each column of cells gives one mean
    per layer; once projected onto the surface those means nearly coincide, and the few nearest
    of them would no longer span the surface around a point. One mean per cell of the denoised
    surface does.
    """
    grouped = group_cells(points, cells.edge)
    if grouped is None:  # the denoised means span more cells than the codes hold: keep them
        return points, normals, fields
    order, starts = grouped
    mass = cells.counts.astype(np.float64)
    means, mean_normals = core.cell_means(points, normals, order, starts, mass)
    total = np.add.reduceat(mass[order], starts[:-1])
    fields = tuple(np.add.reduceat((mass * f)[order], starts[:-1]) / total for f in fields)
    return means, mean_normals, fields


def refine(points, surface, normals, surface_k, sigma_n, clock):
    """Project each of ``points`` onto the denoised cell means ``surface`` (unit ``normals``).

    The feature-aware quadratic of each cell mean's ``surface_k`` nearest means is fitted once,
    in the frame of the mean and its normal (:func:`fit_surface`). Each point then moves onto
    the quadratics of its :data:`BLEND` nearest means, each along its mean's normal, by the
    mean of those steps weighted by the inverse distance to the means (:func:`onto_fits`). One
    fit per mean, not per point: the fits cost what the iterations on the means cost, whatever
    the number of points; the blend leaves no seams where the nearest mean changes.

    Returns
    -------
    moved : (n, 3) float64
    out_normals : (n, 3) float64
        The normal of each point's nearest mean.
    nearest : (n,) int64
        Row of ``surface`` nearest to each point (the source of its per-point fields).
    record : dict
        ``held_points``, ``mean_residual`` and ``fit_degree`` of the nearest means' fits, as an
        iteration's.
    held : (n,) bool
        The points that stayed where they were: no fit of theirs gave a step within its
        support (:func:`pssd_fast.core.evaluate_fits`).
    """
    coef, rms, degree = fit_surface(surface, normals, surface_k, sigma_n, clock)
    moved, held, nearest = clock.run("surface_update", onto_fits, points, surface, normals,
                                     coef)
    return moved, normals[nearest], nearest, fit_record(held, nearest, rms, degree), held


def fit_surface(surface, normals, surface_k, sigma_n, clock):
    """:func:`refine`'s fits: coefficients, RMS residual and degree of the feature-aware
    quadratic of each cell mean's ``surface_k`` nearest means (``core.surface_fits``)."""
    k = min(surface_k, surface.shape[0])
    lists = clock.run("surface_neighbors", knn_graph, surface, k, False)
    return clock.run("surface_fit", core.surface_fits, surface, normals, lists, sigma_n)


def fit_record(held, nearest, rms, degree):
    """``held_points``, ``mean_residual`` and ``fit_degree`` of the points' nearest fits."""
    return fit_summary(int(held.sum()), float(rms[nearest].sum()),
                       np.bincount(degree[nearest], minlength=7), nearest.shape[0])


def fit_summary(held_points, residual_sum, degree_counts, n):
    """:func:`fit_record` from its sums over ``n`` points (those of several tiles added)."""
    return {"held_points": held_points, "mean_residual": residual_sum / n,
            "fit_degree": {name: int(degree_counts[code])
                           for name, code in core.AWARE_FIT_DEGREES.items()}}


def describe(noise, edge, counts, surface, surface_k, fit):
    """``stats["auto_k"]["coarse"]``: the noise, the cells' edge, number and mean points, the
    surface points and their fits' ``surface_k``, and the ``fit`` of :func:`fit_record`."""
    return {"noise": noise, "cell_edge": edge, "cells": int(counts.shape[0]),
            "mean_points": float(counts.mean()), "surface_points": int(surface.shape[0]),
            "surface_k": surface_k, **fit}


#: Nearest cell means whose fits each input point moves onto (docs/DECISIONS.md, "Scan sizes").
BLEND = 3


def onto_fits(points, surface, normals, coef):
    """:func:`refine`'s last step, in chunks whose query results stay small: the points moved
    onto the fits ``coef`` of :func:`fit_surface`, those held, the nearest mean of each."""
    n = points.shape[0]
    count = min(BLEND, surface.shape[0])
    tree = kdtree(surface)
    moved = np.empty_like(points)
    held = np.empty(n, np.bool_)
    nearest = np.empty(n, np.int64)
    chunk = max(1, QUERY_ENTRIES // count)
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        distance, rows = tree.query(points[start:stop], k=count)
        rows = rows.reshape(-1, count).astype(np.int64)
        moved[start:stop], held[start:stop] = core.evaluate_fits(
            points[start:stop], surface, normals, coef, rows, distance.reshape(-1, count))
        nearest[start:stop] = rows[:, 0]
    return moved, held, nearest
