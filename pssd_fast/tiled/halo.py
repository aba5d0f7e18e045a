"""Tiles with halos, for clouds the presets iterate on their points (docs/ALGORITHM.md,
"Tiled runs").

A tile is a range of the cloud's Morton order (starting at a multiple of :data:`ALIGN`). Each
iteration is one task per tile: the tile's own points and every point within a *halo width*
of the boxes around runs of them, at their positions of that iteration, go through the
feature-aware iteration, and the task keeps its own points' results. A point's move reads the
lists of the points within two hops of it (its normal is filtered over its list, each listed
normal comes from a PCA over its own list; in the first iteration three hops, as that normal
is shifted to the PCA of one of its neighbours' lists) and the positions one hop further; the
feature intensity reads the lists of the points within ``R`` of it. A list is exact when the
point is farther from the edge of the halo than its farthest neighbour: every point within its
reach is then in the task. The task checks this for every list it reads, and reports a halo
too thin instead of a result; the tile runs again with a halo twice as wide.

The means over the whole cloud (the centroid behind the first PCA's signs, the mean spacing
behind ``R`` and the mean residual behind the likelihood) are taken over all points in Morton
order, as :func:`pssd_fast.denoise` takes them, so the result is bit-identical to it.
"""
import time
from typing import NamedTuple, Optional

import numpy as np

from .. import core
from .._threads import threads
from ..graph import bounds, knn_graph, truncate_graph
from ..pipelines import aware
from ..pipelines.normals import pca, shifted
from ..progress import Clock
from ..run import Iterated
from ..pipelines import walks

#: Tiles start at multiples of this rank: the feature kernel grows its regions for blocks of
#: 64 consecutive points, and a block's regions are summed in the order they were grown.
ALIGN = 64
#: A tile's halo is the points near the boxes of this many runs of its points.
PIECES = 32
#: The first halo width, in mean list radii: three hops of lists (a point, its neighbours and
#: theirs, each read to its list's end), each up to 4/3 of the mean radius (a tile whose
#: halo is too thin runs again).
FIRST_WIDTH = 4.0


def tiles(n, tile_points):
    """Consecutive rank ranges ``(start, stop)`` of at most ``tile_points`` points (rounded
    down to a multiple of :data:`ALIGN`, at least one such block)."""
    size = max(ALIGN, tile_points - tile_points % ALIGN)
    return [(start, min(n, start + size)) for start in range(0, n, size)]


def box(points):
    """The bounding box of ``points``: ``(low, high)``."""
    return bounds(points)


def boxes(points):
    """The bounding boxes ``(p, 2, 3)`` of the runs :func:`cuts` of ``points`` (Morton
    order): together they follow the tile's shape, where one box around a range of the curve
    may hold several times its volume."""
    ends = cuts(points.shape[0])
    return np.stack([np.stack(box(points[a:b])) for a, b in zip(ends[:-1], ends[1:])])


def cuts(m):
    """The ends of up to :data:`PIECES` consecutive runs of ``m`` points, as even as can be."""
    return np.linspace(0, m, min(PIECES, m) + 1).astype(np.int64)


def within(points, region):
    """The mask of ``points`` inside any of the boxes ``region`` ``(p, 2, 3)``."""
    low, high = region[:, 0].min(axis=0), region[:, 1].max(axis=0)
    rows = np.flatnonzero(_inside(points, low, high))
    near = points[rows]
    hit = np.zeros(rows.shape[0], np.bool_)
    for low, high in region:
        hit |= _inside(near, low, high)
    inside = np.zeros(points.shape[0], np.bool_)
    inside[rows[hit]] = True
    return inside


def _inside(points, low, high):
    inside = (points[:, 0] >= low[0]) & (points[:, 0] <= high[0])
    for a in (1, 2):
        inside &= (points[:, a] >= low[a]) & (points[:, a] <= high[a])
    return inside


def _exact(lists, points, region, rows):
    """Whether the lists of ``rows`` (a mask) are exact: each point lies farther inside one of
    the boxes ``region`` than its farthest neighbour, so every point within its reach is in
    the task. Each box is tried on the points no box before it cleared."""
    left = np.flatnonzero(rows)
    for low, high in region:
        near = points[left]
        inside = np.minimum(near - low, high - near).min(axis=1)
        left = left[lists.radius[left] >= inside]
        if not left.size:
            return True
    return False


def _closure(lists, rows):
    """The mask of ``rows`` (a mask) and every point in their lists."""
    k = lists.indptr[1] - lists.indptr[0]
    reach = rows.copy()
    reach[lists.indices.reshape(-1, k)[rows].ravel()] = True
    return reach


class Tile(NamedTuple):
    """A tile's points in one iteration: its own ``n_own`` first, then its halo, every point
    of the cloud of ``n`` in the boxes ``region`` (``(p, 2, 3)``, lows and highs; None, or
    all ``n`` points: no halo to check)."""

    points: np.ndarray
    n_own: int
    n: int
    region: Optional[np.ndarray]


class Fit(NamedTuple):
    """What an iteration fits a tile with: the lists' ``k`` and ``sigma_n`` (as in
    :func:`pssd_fast.pipelines.aware.step`), ``radius``, ``R`` of the feature intensity on the
    last iteration (else None), and ``walk``, the iteration's plan of ``select_scales``
    (:class:`pssd_fast.routes.scales.ScalePlan`, else None)."""

    k: int
    sigma_n: float
    radius: Optional[float]
    walk: object


def spacing(tile, k, n_jobs):
    """Distance from each of the ``tile``'s own points to its nearest neighbour in the
    ``k``-lists of the iteration; None when the halo is too thin."""
    points, n_own, n, region = tile
    region = None if points.shape[0] == n else region
    if region is not None and points.shape[0] <= k:
        return None
    with threads(n_jobs):
        lists = knn_graph(points, k, False)
        if region is not None and not _exact(lists, points, region, _own(points, n_own)):
            return None
        return lists.nearest[:n_own].copy()


def _own(points, n_own):
    """The mask of the first ``n_own`` of ``points``."""
    mask = np.zeros(points.shape[0], np.bool_)
    mask[:n_own] = True
    return mask


def step(tile, normals, given, centroid, fit, n_jobs):
    """One feature-aware iteration of a tile's own points.

    Parameters
    ----------
    tile : Tile
        The tile's own points, then its halo, at this iteration's positions (float64).
    normals : (m, 3) float64 or None
        The normals of the iteration before (the hints of the PCA), the caller's normals
        (``given``: used as they are), or None (the PCA's hints point away from
        ``centroid``, the whole cloud's).
    fit : Fit
        The iteration's ``k``, ``sigma_n``, ``radius`` and ``walk``.

    Returns
    -------
    dict or None
        None when the halo is too thin. Else, for the own points: ``moved``, ``normals`` (the
        filtered ones), ``rms``, ``feature`` (None but on the last iteration), ``held`` (the
        mask of those held in place); and the counts of the iteration's record: ``rms_sum``,
        ``degree`` counts, ``degenerate``,
        ``step_sum``, and ``scales``: with a ``walk``, how many own points kept each length
        and took the plane (:func:`pssd_fast.pipelines.walks.kept_counts`), else None.
    """
    points, n_own, n, region = tile
    k, sigma_n, radius, walk = fit
    region = None if points.shape[0] == n else region
    longest = k if walk is None else int(walk.lengths[-1])
    if region is not None and points.shape[0] <= longest:
        return None
    with threads(n_jobs):
        long_lists = None
        if walk is None:
            lists = knn_graph(points, k, False)
        else:
            # The walks' lists, cut to k, are the iteration's (as in pssd_fast.denoise).
            long_lists = knn_graph(points, longest, False)
            lists = truncate_graph(long_lists, points, k)
        if region is not None:
            reach = _own(points, n_own)
            if walk is not None:
                # The walked fits read the long lists and their members' filtered normals.
                if not _exact(long_lists, points, region, reach):
                    return None
                reach = _closure(long_lists, reach)
            reach = _closure(lists, _closure(lists, reach))
            if normals is None:
                reach = _closure(lists, reach)  # shifted normals read their candidates' lists
            if not _exact(lists, points, region, reach):
                return None
            if radius is not None and not _exact(
                    lists, points, region, within(points, widened(boxes(points[:n_own]),
                                                                  radius))):
                return None
        if given:
            nrm, degenerate = normals, np.zeros(points.shape[0], np.bool_)
        else:
            hints = points - centroid if normals is None else normals
            first = normals is None  # shifted (docs/ALGORITHM.md, "Shifted normals")
            nrm, degenerate, planes = pca(points, lists, hints, first)
            if first:
                nrm = shifted(points, nrm, lists, planes, k)
        clock = Clock(None, 0, 1)
        moved, filtered, rms, degree, held, kept = aware.fit_and_move(
            points, nrm, lists, sigma_n, clock, None, walk, long_lists)
        feature = None
        if radius is not None:
            feature = aware.voted_feature(points, nrm, lists, radius)[:n_own].copy()
        own_rms = rms[:n_own].copy()
        return {
            "moved": moved[:n_own].copy(), "normals": filtered[:n_own].copy(), "rms": own_rms,
            "feature": feature, "held": held[:n_own].copy(), "rms_sum": float(own_rms.sum()),
            "degree": np.bincount(degree[:n_own], minlength=7),
            "degenerate": int(degenerate[:n_own].sum()),
            "step_sum": float(np.linalg.norm(moved[:n_own] - points[:n_own], axis=1).sum()),
            "scales": None if kept is None else walks.kept_counts(
                walk.lengths, kept[0][:n_own], kept[1][:n_own]),
        }


def first_width(probe_radius, probe_k, k):
    """The first halo width: :data:`FIRST_WIDTH` times the mean radius of ``k``-lists, from
    the noise probe's (on a surface the radius grows as the square root of ``k``)."""
    return FIRST_WIDTH * probe_radius * np.sqrt(k / probe_k)


def pairwise_mean(read, n, block=1 << 20):
    """``np.mean`` of the ``n`` values that ``read(start, stop)`` gives by ranges, to the last
    bit, reading at most ``block`` at a time: numpy sums a contiguous array pairwise (halves
    split at multiples of 8, down to 128 values), so a half's sum is ``np.add.reduce`` of it."""
    def pairwise(start, count):
        if count <= max(block, 128):
            return np.add.reduce(read(start, start + count))
        half = count // 2
        half -= half % 8
        return pairwise(start, half) + pairwise(start + half, count - half)

    return float(pairwise(0, n) / n)


def orient_pointwise(points, normals, orient, centroid):
    """``normals`` flipped in place, one by one, to face ``orient``: ``"outward"`` (away from
    ``centroid``), ``"up"`` (+z) or a viewpoint (relative to the points' frame)."""
    if isinstance(orient, str):
        towards = points - centroid if orient == "outward" else np.array([0.0, 0.0, 1.0])
    else:
        towards = orient - points
    flip = np.einsum("ij,ij->i", normals, np.broadcast_to(towards, normals.shape)) < 0.0
    normals[flip] *= -1.0


def iterate(current, given, plan, sigma_n, spans, width, runner):
    """The iterations of ``plan`` (:class:`pssd_fast.routes.plan.Plan`: its ``k``,
    ``iterations`` and ``walks``) of the feature-aware pipeline on ``current`` (Morton order),
    tile by tile over the rank ranges ``spans``, each iteration's tiles run by ``runner`` (see
    :class:`pssd_fast.tiled.runner._Runner`); ``given``: the caller's normals or None,
    ``width``: the first halo width. Returns an :class:`pssd_fast.run.Iterated`, as
    :func:`pssd_fast.run.iterate` does."""
    k, iterations, scale_plan = plan.k, plan.iterations, plan.walks
    n = current.shape[0]
    widths = [width] * len(spans)
    normals = given
    records = []
    held = np.zeros(n, np.bool_)
    for t in range(iterations):
        started = time.perf_counter()
        centroid = current.mean(axis=0) if normals is None else None
        cloud = box(current)

        def spacing_args(i, width):
            (a, b), (rows, region) = spans[i], _candidates(current, *spans[i], width, cloud)
            return Tile(current[rows], b - a, n, region), k

        def step_args(i, width):
            (a, b), (rows, region) = spans[i], _candidates(current, *spans[i], width, cloud)
            return (Tile(current[rows], b - a, n, region),
                    None if normals is None else normals[rows], t == 0 and given is not None,
                    centroid, Fit(k, sigma_n, radius,
                                  None if scale_plan is None else scale_plan.at(t)))

        radius = None
        if t == iterations - 1:
            nearest = each_tile(runner, "tile_spacing", t, iterations, spacing, widths,
                                spacing_args)
            radius = aware.region_radius(float(np.mean(np.concatenate(nearest))))
        out = each_tile(runner, "tile_step", t, iterations, step, widths, step_args)
        current = np.concatenate([o["moved"] for o in out])
        normals = np.concatenate([o["normals"] for o in out])
        held |= np.concatenate([o["held"] for o in out])
        records.append(record(out, n, widths, started))
    rms = np.concatenate([o["rms"] for o in out])
    likelihood, _ = core.sampling_likelihood(rms, "exp")
    return Iterated(current, normals, (likelihood, np.concatenate([o["feature"] for o in out])),
                    records, held)


def record(out, n, widths, started):
    """An iteration's record for ``stats`` from its tiles' results (:func:`step`)."""
    found = aware.step_record({"tiles": time.perf_counter() - started},
                              sum(int(o["held"].sum()) for o in out),
                              sum(o["rms_sum"] for o in out), n,
                              np.sum([o["degree"] for o in out], axis=0))
    found["degenerate_normals"] = sum(o["degenerate"] for o in out)
    found["mean_step"] = sum(o["step_sum"] for o in out) / n
    found["halo_widths"] = [float(min(widths)), float(max(widths))]
    if out[0]["scales"] is not None:
        found["scales"] = {"lengths": out[0]["scales"]["lengths"],
                           "kept": np.sum([o["scales"]["kept"] for o in out], axis=0).tolist(),
                           "flat": sum(o["scales"]["flat"] for o in out)}
    return found


def each_tile(runner, stage, t, iterations, func, widths, arguments):
    """``func(*arguments(i, widths[i]))`` for every tile ``i``, each tile whose halo was too
    thin (``func`` gave None) again with a halo twice as wide; the results in the tiles'
    order."""
    results = [None] * len(widths)
    todo = list(range(len(widths)))
    while todo:
        found = runner.map(stage, t + 1, iterations, func,
                           [arguments(i, widths[i]) for i in todo])
        again = []
        for i, result in zip(todo, found):
            if result is None:
                widths[i] *= 2.0
                again.append(i)
            else:
                results[i] = result
        todo = again
    return results


def covers(region, cloud):
    """Whether one of the boxes ``region`` holds the box ``cloud`` (``(low, high)``)."""
    return bool((np.all(region[:, 0] <= cloud[0], axis=1)
                 & np.all(region[:, 1] >= cloud[1], axis=1)).any())


def _candidates(current, a, b, width, cloud):
    """The rows of a tile's task: its own ``a..b-1``, then every other point inside the
    :func:`boxes` of its points widened by ``width``, in rank order; and those boxes, or None
    when they hold the whole cloud."""
    region = widened(boxes(current[a:b]), width)
    if covers(region, cloud):
        n = current.shape[0]
        return np.concatenate((np.arange(a, b), np.arange(a), np.arange(b, n))), None
    inside = within(current, region)
    inside[a:b] = False
    return np.concatenate((np.arange(a, b), np.flatnonzero(inside))), region


def widened(region, width):
    """The boxes ``region`` grown by ``width`` on every side."""
    return region + np.array([-width, width])[None, :, None]
