"""The points near features on their own: the last pass of the default's ``"edges"`` route
(docs/ALGORITHM.md, "Routes"; docs/DECISIONS.md, "One default on every cloud").

The cells route averages the noise down over cell means, and where the noise is below the
point spacing its fits round the sharp edges: a fit over a few dozen means spans both faces of
an edge. This pass gives the points near a feature fits of their own. The means whose feature
intensity is in the top :data:`EDGES` ``fraction`` are flagged; each point takes its nearest
mean's flag. The flagged points then run the feature-aware iterations of the points route over
lists of ``k`` neighbours, while every other point within ``reach`` list radii of a flagged
mean stays where the cells put it and lends its position and normal to the fits. The pass
reads only those points (the *zone*), in the cloud's order, so a tiled run gathers the same
rows and gets the same bits.
"""
import numpy as np

from .._threads import kdtree
from ..graph import QUERY_ENTRIES, ListScales, morton_order
from ..pipelines import aware
from ..pipelines.normals import estimated_normals
from ..progress import Clock

#: ``fraction``: the share of the cell means flagged (highest feature intensity first);
#: ``k``: list length of the flagged points, interpolated linearly in ``log`` of the noise
#: probe's ``sigma / r`` (lists of 32) and ``log k`` between the anchors ``(ratio, k)`` and
#: held at the end values outside them (the noise wants longer lists to average down);
#: ``iterations``: their feature-aware iterations; ``reach``: the zone's radius around a
#: flagged mean, in mean list radii at ``k``. Chosen on the CAD part at 100,000 to 1,000,000
#: points and 0.05% to 1% noise (docs/DECISIONS.md, "One default on every cloud: the edges
#: route").
EDGES = {"fraction": 0.15, "k": ((0.1, 48), (0.16, 96), (0.33, 128)), "iterations": 2,
         "reach": 1.5}

#: Codes of :func:`zones`.
OUTSIDE, SUPPORT, FLAGGED = 0, 1, 2


def zones(surface, feature, radius):
    """The zone code of each cell mean: :data:`FLAGGED` for the top ``EDGES["fraction"]`` of
    ``feature`` (at least one mean), :data:`SUPPORT` within ``radius`` of a flagged mean,
    :data:`OUTSIDE` elsewhere."""
    m = surface.shape[0]
    top = max(1, int(round(EDGES["fraction"] * m)))
    # The top-ranked means, ties broken by row: no quantile interpolation to depend on.
    flagged = np.argsort(-feature, kind="stable")[:top]
    code = np.full(m, OUTSIDE, np.int8)
    distance, _ = kdtree(np.ascontiguousarray(surface[flagged])).query(
        surface, k=1, distance_upper_bound=radius)
    code[distance <= radius] = SUPPORT
    code[flagged] = FLAGGED
    return code


def list_length(probe):
    """The flagged points' ``k`` at the noise ``probe``'s ratio (``EDGES["k"]``)."""
    return aware.interpolated_k(probe["ratio"], EDGES["k"])


def reach(probe, k):
    """The zone's radius from the noise ``probe`` of the plan (``probe_radius`` of
    ``probe_k`` lists, scaled to the whole cloud): ``EDGES["reach"]`` list radii at ``k``,
    as on a surface (radius as ``sqrt(k)``)."""
    return EDGES["reach"] * probe["probe_radius"] * np.sqrt(k / probe["probe_k"])


def finish(setting, fine, placed, normals, held, nearest, code, rows, given, keep_normals,
           sigma_n, clock):
    """The pass on a whole cloud, in place: ``placed``, ``normals`` and ``held`` of its
    flagged points replaced by :func:`sharpen`'s.

    Parameters
    ----------
    setting : dict
        The plan's ``edges`` (its ``k``); the counts of the pass are added to it.
    fine, placed : (n, 3) float64
        The points where they came in and where the cells put them.
    normals : (n, 3) float64
        Their normals from the cells.
    held : (n,) bool
        The points the cells held.
    nearest : (n,) int64
        Each point's nearest cell mean, whose ``code`` (:func:`zones`) it takes.
    rows : (n,) int64
        Each point's row in the input, which orders the zone (:func:`canonical`).
    given : (n, 3) float64 or None
        The caller's normals.
    keep_normals, sigma_n, clock
        As :func:`sharpen` takes them.
    """
    zone = np.flatnonzero(code[nearest] != OUTSIDE)
    picked, moved, out, held_now = gathered(
        setting, rows[zone], fine[zone], placed[zone], normals[zone],
        code[nearest[zone]] == FLAGGED, None if given is None else given[zone], keep_normals,
        sigma_n, clock)
    changed = zone[picked]
    placed[changed] = moved
    normals[changed] = out
    held[changed] |= held_now


def gathered(setting, rows, fine, placed, normals, flagged, given, keep_normals, sigma_n,
             clock):
    """The pass over a zone gathered in any order (its points' input ``rows``, ``fine`` and
    ``placed`` positions, cells' ``normals``, ``flagged`` mask and ``given`` normals or
    None): the flagged points start from ``fine``, the zone is put in :func:`canonical`
    order and :func:`sharpen`ed with the plan's ``setting["k"]``. Returns the flagged points'
    indices into the gathered arrays, in that order, and :func:`sharpen`'s outputs for them;
    the counts of the pass go into ``setting``."""
    start = placed.copy()
    start[flagged] = fine[flagged]
    order = canonical(rows, start)
    moved, out, held = sharpen(start[order], normals[order], flagged[order],
                               None if given is None else given[order], keep_normals,
                               setting["k"], sigma_n, clock)
    picked = order[flagged[order]]
    setting.update(flagged=int(picked.shape[0]), zone=int(order.shape[0]),
                   held=int(held.sum()))
    return picked, moved, out, held


def canonical(rows, start):
    """The order the pass takes a zone's points in, the same however they were gathered:
    by input ``rows``, then along the Morton curve of their ``start`` positions (so that
    neighbours are near in memory)."""
    by_row = np.argsort(rows, kind="stable")
    return by_row[morton_order(np.ascontiguousarray(start[by_row]))]


def sharpen(start, normals, flagged, given, keep_normals, k, sigma_n, clock):
    """The flagged points of a zone iterated on their own lists.

    Parameters
    ----------
    start : (z, 3) float64
        The zone's points (in :func:`canonical` order): the flagged ones where they came in,
        the others where the cells put them.
    normals : (z, 3) float64
        The unit normals the cells gave the zone's points: the unflagged ones keep theirs, and
        the flagged ones' are signed like theirs.
    flagged : (z,) bool
        The points that iterate.
    given : (z, 3) float64 or None
        The caller's normals: the flagged points take them in the first iteration (in every
        one with ``keep_normals``), as on the points route; else PCA normals of their lists.
    keep_normals : bool
        See ``given``.
    k : int
        The flagged points' list length (capped at the zone's points).
    sigma_n : float
        The feature-aware fit's normal width.
    clock : pssd_fast.progress.Clock
        Times the stages (``edge_neighbors``, ``edge_normals``, ``edge_fit``, summed over the
        pass's iterations).

    Returns
    -------
    moved : (f, 3) float64
        The flagged points' new positions.
    out_normals : (f, 3) float64
        Their filtered normals of the last iteration.
    held : (f,) bool
        Those held in place in some iteration (their step was not within their list).
    """
    rows = np.flatnonzero(flagged)
    current = start.copy()
    normals = normals.copy()
    held = np.zeros(rows.shape[0], np.bool_)
    k = min(k, current.shape[0])
    for iteration in range(EDGES["iterations"]):
        graph = clock.run("edge_neighbors", zone_lists, current, rows, k)
        if given is not None and (iteration == 0 or keep_normals):
            nrm = given.copy()
        else:
            # Shifted normals in the first iteration, as on the points route.
            nrm, _ = clock.run("edge_normals", estimated_normals, current, graph,
                               normals, None, None, k if iteration == 0 else None)
        nrm[~flagged] = normals[~flagged]
        # Its stages, timed as one: the iteration's own filter, fit and update keep theirs.
        moved, filtered, _, _, held_now, _ = clock.run(
            "edge_fit", aware.fit_and_move, current, nrm, graph, sigma_n,
            Clock(None, iteration, EDGES["iterations"]))
        current[rows] = moved[rows]
        normals[rows] = filtered[rows]
        held |= held_now[rows]
    return current[rows], normals[rows], held


def zone_lists(points, rows, k):
    """Lists of ``k`` nearest ``points`` for the ``rows`` (the point itself first), and of the
    point alone for every other row, as a :class:`~pssd_fast.graph.ListScales`. The query
    runs in chunks of ``QUERY_ENTRIES // k`` rows, as :func:`pssd_fast.graph.knn_graph`'s."""
    n = points.shape[0]
    tree = kdtree(points)
    lengths = np.ones(n, np.int64)
    lengths[rows] = k
    indptr = np.concatenate(([0], np.cumsum(lengths)))
    indices = np.repeat(np.arange(n, dtype=np.int32 if n < 2**31 else np.int64), lengths)
    radius = np.zeros(n)
    nearest = np.zeros(n)
    chunk = max(1, QUERY_ENTRIES // k)
    for first in range(0, rows.shape[0], chunk):
        part = rows[first:first + chunk]
        distance, index = tree.query(points[part], k=k)
        index = index.reshape(-1, k).astype(np.int64)
        distance = np.asarray(distance, np.float64).reshape(-1, k)
        _self_first(index, part)
        indices[indptr[part][:, None] + np.arange(k)] = index
        radius[part] = distance[:, -1]
        nearest[part] = distance[:, 1] if k > 1 else 0.0
    return ListScales(indptr, indices, radius, nearest)


def _self_first(index, rows):
    """Each of ``rows`` moved to the front of its list in ``index`` (in place). A flagged
    point's input position may coincide with another point's placement; the point itself goes
    first, as in every list of the library."""
    own = index == rows[:, None]
    tied = ~own[:, 0]
    if tied.any():
        at = own[tied].argmax(axis=1)
        swapped = index[tied]
        swapped[np.arange(at.shape[0]), at] = swapped[:, 0]
        swapped[:, 0] = rows[tied]
        index[tied] = swapped
