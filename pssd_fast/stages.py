"""The stages of the robust method as public functions, for tools that use pssd_fast as a backend.

Each public function takes points in the caller's order (and optionally normals and a
neighbour graph from :func:`pssd_fast.neighbors`, to share work between stages) and returns new
arrays in the input's float dtype. The same stages on validated float64 arrays, which the
pipelines of :func:`pssd_fast.denoise` use, are in :mod:`pssd_fast.core`.
"""
from typing import NamedTuple

import numpy as np

from . import core, interop
from ._threads import threads
from ._validation import (as_normals, as_points, auto, check_choice, check_float, check_k,
                          check_orient)
from .graph import NeighborGraph, check_graph, curve_order, knn_graph
from .run import outlier_scores

class MLSFit(NamedTuple):
    """Result of :func:`mls_fit`.

    Attributes
    ----------
    projections : (n, 3) ndarray
        ``q_i``, each point projected onto its local MLS cubic.
    residuals : (n,) ndarray
        ``d_i``, the weighted mean distance of the neighbours to the fitted cubic.
    degree : (n,) int8
        Degree actually fitted: 3 (cubic), 2 (quadratic fallback) or 0 (plane fallback).
    curvature : (n,) ndarray
        Mean curvature of the fitted surface, from the derivatives of the cubic at the local
        origin (no extra cost); positive where the surface bends away from the normal.
    h : float
        The kernel width used.
    """

    projections: np.ndarray
    residuals: np.ndarray
    degree: np.ndarray
    curvature: np.ndarray
    h: float


class _Sorted(NamedTuple):
    """Validated inputs of a public stage, rows in Morton order (better locality in every
    kernel: the region growing runs 7x faster on sorted than on shuffled input)."""

    order: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    graph: NeighborGraph
    dtype: np.dtype

    def unsort(self, values):
        """``values`` (one row per sorted point) back in the caller's order and float dtype."""
        out = np.empty_like(values)
        out[self.order] = values
        return out.astype(self.dtype, copy=False) if out.dtype.kind == "f" else out


def _sorted_graph(graph, order):
    """A caller-order graph with its rows (and the indices in them) in the order ``order``."""
    n = order.shape[0]
    rank = np.empty(n, graph.indices.dtype)
    rank[order] = np.arange(n, dtype=graph.indices.dtype)
    lengths = np.diff(graph.indptr)[order]
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(lengths, out=indptr[1:])
    within = np.arange(indptr[-1], dtype=np.int64) - np.repeat(indptr[:-1], lengths)
    entries = np.repeat(graph.indptr[:-1][order], lengths) + within
    return NeighborGraph(indptr, rank[graph.indices[entries]], graph.distances[entries])


def _prepare(points, normals_, k, graph, n_jobs, orient=None, estimate=True):
    """Validate inputs, sort them along a Morton curve, build the graph (or sort the caller's)
    and, with ``estimate``, estimate normals where not given (oriented along ``orient``,
    default outward)."""
    pts, dtype = as_points(interop.coordinates(points))
    n = pts.shape[0]
    hints = None if orient is None else as_points(orient, "orient")[0]
    if hints is not None and hints.shape[0] != n:
        raise ValueError(f"orient must have one row per point: got {hints.shape[0]} rows for "
                         f"{n} points")
    nrm = None if normals_ is None else as_normals(normals_, n)
    graph = None if graph is None else _of_these(check_graph(graph, n), pts)
    k = None if graph is not None else check_k(k, n, denoising=False)
    with threads(n_jobs):
        order = curve_order(pts)
        pts = pts[order]
        graph = knn_graph(pts, k) if graph is None else _sorted_graph(graph, order)
        if nrm is not None:
            nrm = nrm[order]
        elif estimate:
            hints = core.outward_hints(pts) if hints is None else hints[order]
            nrm, _ = core.pca_normals(pts, graph, hints)
    return _Sorted(order, pts, nrm, graph, dtype)


def _of_these(graph, points, rows=256):
    """``graph``, or ValueError where the distances it holds for up to ``rows`` evenly spread
    rows are not those of ``points``: a graph of other points (or of these in another order)
    with the same number of rows."""
    at = np.unique(np.linspace(0, points.shape[0] - 1, rows).astype(np.int64))
    for i in at:
        members = graph.indices[graph.indptr[i]:graph.indptr[i + 1]]
        held = graph.distances[graph.indptr[i]:graph.indptr[i + 1]]
        actual = np.sqrt(((points[members] - points[i]) ** 2).sum(axis=1))
        if not np.allclose(held, actual, rtol=1e-6, atol=1e-9 * max(float(actual.max()), 1e-300)):
            raise ValueError(f"graph.distances of row {i} are not those of these points: was "
                             f"the graph built for them, in this order (pssd_fast.neighbors)?")
    return graph


def _fit(points, normals_, k, h, graph, n_jobs):
    """The MLS stage for the public functions, in Morton order: a float64 :class:`MLSFit`."""
    h = auto(h, lambda v: check_float(v, "h", positive=True))
    run = _prepare(points, normals_, k, graph, n_jobs)
    h = core.default_h(run.graph, h)
    with threads(n_jobs):
        return run, MLSFit(*core.mls_fit(run.points, run.normals, run.graph, h), h)


def estimate_normals(points, *, k=25, graph=None, orient=None, n_jobs=None):
    """Estimate unit normals by PCA over each point's ``k`` nearest neighbours.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates, float32 or float64 (other real dtypes are computed as float64).
    k : int, default 25
        Neighbourhood size including the point itself (ignored when ``graph`` is given).
    graph : NeighborGraph, optional
        Precomputed graph from :func:`pssd_fast.neighbors` for these points, in this order
        (its distances are checked on 256 rows; ``k`` is then ignored).
    orient : {"outward", "up"}, array_like of shape (3,) or (n, 3), optional
        How to sign the normals (PCA alone fixes no sign). ``"outward"``, ``"up"`` or a
        viewpoint ``(x, y, z)``: made consistent by propagation over the neighbour graph
        (Hoppe et al.'s minimum spanning tree, weights ``1 - |n_i . n_j|``), then each
        connected component is turned as a whole to point outward (away from the cloud's
        centroid on balance: outward for closed surfaces of any shape), up (``+z`` on
        balance; terrain, aerial scans) or towards the viewpoint on balance (a scanner's
        position). An ``(n, 3)`` array: reference directions, each normal flipped to have a
        non-negative dot product with its row. ``None`` (default): each normal points away
        from the cloud's centroid on its own, which is outward only for star-shaped objects.
    n_jobs : int or None
        Threads (see :func:`pssd_fast.denoise`).

    Returns
    -------
    (n, 3) ndarray
        Unit normals, in the input's float dtype.

    Notes
    -----
    docs/ALGORITHM.md step 0: the eigenvector of the smallest eigenvalue of the covariance of the
    list about its centroid. Collinear or coincident lists have no plane; their normal is an
    arbitrary but deterministic unit vector.

    Examples
    --------
    >>> import numpy as np
    >>> import pssd_fast
    >>> from pssd_fast import datasets
    >>> cloud = datasets.make("sphere", n_points=2000, seed=0)
    >>> normals = pssd_fast.estimate_normals(cloud.points, orient="outward")
    >>> normals.shape, normals.dtype
    ((2000, 3), dtype('float64'))
    >>> cosines = np.einsum("ij,ij->i", normals, cloud.normals)  # against the true normals
    >>> bool(cosines.min() > 0.95)  # every one outward, within 18 degrees
    True
    """
    propagate = None
    if orient is not None and np.ndim(orient) != 2:
        propagate, orient = check_orient(orient), None
    run = _prepare(points, None, k, graph, n_jobs, orient)
    if propagate is not None:
        with threads(n_jobs):
            core.orient_normals(run.points, run.normals, run.graph, propagate)
    return run.unsort(run.normals)


def outlier_score(points, *, k=core.OUTLIER_K, graph=None, n_jobs=None):
    """Per-point outlier score: points scoring above 1 are flagged as outliers.

    Parameters
    ----------
    points, graph, n_jobs
        As in :func:`mls_fit`.
    k : int, default 64
        Neighbourhood size including the point itself (ignored when ``graph`` is given).

    Returns
    -------
    (n,) ndarray
        The larger of two ratios: the distance to the ``k``-th nearest neighbour over twice its
        median over the cloud (points far from everything), and the distance to the
        least-squares plane of the other neighbours over the larger of six times its median and
        three times those neighbours' own median distance to their plane (points just off the
        surface, but not a sharp edge's, whose neighbours lie on two faces). About 0.5 on a
        surface; the threshold is 1.

    Notes
    -----
    Medians are taken over the whole cloud, so the score assumes roughly even sampling and
    noise; docs/DECISIONS.md ("Outliers") gives the measured rates (on clouds with 2%
    uniform outliers: at most 0.5% of surface points flagged at noise up to 1% of the
    diagonal; outliers within a few noise widths of the surface are not told apart).

    Examples
    --------
    >>> import numpy as np
    >>> import pssd_fast
    >>> from pssd_fast import datasets
    >>> surface = datasets.make("sphere", n_points=2000, seed=0).points
    >>> strays = np.random.default_rng(1).uniform(-1, 1, (10, 3))
    >>> score = pssd_fast.outlier_score(np.vstack([surface, strays]))
    >>> score.shape, f"{np.median(score):.2f}"
    ((2010,), '0.50')
    >>> np.flatnonzero(score > 1)  # the ten strays, rows 2000 to 2009
    array([2000, 2001, 2002, 2003, 2004, 2005, 2006, 2007, 2008, 2009])
    """
    if graph is None:
        pts, dtype = as_points(interop.coordinates(points))
        return outlier_scores(pts, n_jobs, k).astype(dtype, copy=False)
    run = _prepare(points, None, k, graph, n_jobs, estimate=False)
    with threads(n_jobs):
        return run.unsort(core.outlier_score(run.points, run.graph))


def mls_fit(points, normals=None, *, k=25, h="auto", graph=None, n_jobs=None):
    """Fit the local MLS cubic of every point and project the point onto it.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    normals : array_like, shape (n, 3), optional
        Normals orienting the reference planes; estimated by PCA when omitted.
    k : int, default 25
        Neighbourhood size including the point itself (the paper's ``k in [20, 35]``).
    h : float or "auto", default "auto"
        Gaussian width of ``theta(d) = exp(-d^2 / h^2)``; ``"auto"``: the mean over all points
        of the distance to the farthest of the ``k`` neighbours.
    graph : NeighborGraph, optional
        Precomputed graph from :func:`pssd_fast.neighbors` for these points, in this order.
    n_jobs : int or None
        Threads (see :func:`pssd_fast.denoise`).

    Returns
    -------
    MLSFit
        Projections ``q_i``, residuals ``d_i``, fitted degree, mean curvature and ``h``.

    Notes
    -----
    Paper Section 2.1 and eq. (1); docs/ALGORITHM.md step 1. The reference plane is the weighted
    centroid and smallest eigenvector of the weighted covariance (a one-step simplification of
    Alexa et al.'s non-linear search). Neighbourhoods that cannot support a cubic (singular or
    ill-conditioned 10x10 normal equations, e.g. collinear or duplicated points) fall back to
    the quadratic, then to the plane ``g = 0``.
    """
    run, fit = _fit(points, normals, k, h, graph, n_jobs)
    return MLSFit(*(run.unsort(a) for a in fit[:4]), fit.h)


def sampling_likelihood(points, normals=None, *, k=25, h="auto", likelihood="exp", graph=None,
                        n_jobs=None):
    """Sampling likelihood ``l_i`` of each point (how likely it lies on the sampled surface).

    Parameters
    ----------
    points, normals, k, h, graph, n_jobs
        As in :func:`mls_fit`.
    likelihood : {"exp", "ratio", "residual"}, default "exp"
        Form of eq. (2), which is missing from the paper's text (docs/ALGORITHM.md step 1):
        ``"exp"``: ``exp(-d_i / dbar)``; ``"ratio"``: ``min(dbar / d_i, 1)``; ``"residual"``:
        ``d_i / dbar`` (the opposite reading); ``dbar`` is the mean of ``d_i`` over the model.

    Returns
    -------
    (n,) ndarray
        ``l_i``; for ``"exp"`` and ``"ratio"`` in (0, 1], 1 on a clean surface.
    """
    check_choice(likelihood, "likelihood", tuple(core.LIKELIHOOD_FORMS))
    run, fit = _fit(points, normals, k, h, graph, n_jobs)
    out, _ = core.sampling_likelihood(fit.residuals, likelihood)
    return run.unsort(out)


def feature_intensity(points, normals=None, *, k=25, radius_factor=10.0, delta=0.2, alpha=0.3,
                      beta=0.3, graph=None, n_jobs=None):
    """Feature intensity ``s_i`` of eq. (3): about 0 on faces, about 1 on edges and corners.

    Parameters
    ----------
    points, graph, n_jobs
        As in :func:`mls_fit`.
    normals : array_like, shape (n, 3), optional
        Unit normals; estimated by PCA when omitted. Only local sign consistency matters.
    k : int, default 25
        Size of the kNN lists; region growing uses their first 9 entries.
    radius_factor : float, default 10
        ``R = radius_factor * |E|``, ``|E|`` the mean nearest-neighbour distance (Section 3).
    delta, alpha, beta : float, default 0.2, 0.3, 0.3
        Thresholds of eq. (3).

    Returns
    -------
    (n,) ndarray
        ``s_i`` in [0, 1].

    Notes
    -----
    Paper Section 3; docs/ALGORITHM.md step 2. ``N_R(i)`` grows breadth-first through 9-nearest-
    neighbour lists, keeping points within ``R`` of ``p_i``, so it does not jump across thin gaps
    (Fig. 3). Each member votes ``n'_j`` (Page et al.) into ``T_i = sum u_j n'_j n'_j^T``.
    """
    radius_factor = check_float(radius_factor, "radius_factor", positive=True)
    delta = check_float(delta, "delta", positive=True)
    alpha = check_float(alpha, "alpha", positive=True)
    beta = check_float(beta, "beta", positive=True)
    run = _prepare(points, normals, k, graph, n_jobs)
    with threads(n_jobs):
        out, _ = core.feature_intensity(run.points, run.normals, run.graph,
                                        radius_factor * core.mean_spacing(run.graph), delta,
                                        alpha, beta)
    return run.unsort(out)


def filter_normals(points, normals=None, *, k=25, graph=None, n_jobs=None):
    """Bilateral filter of the normals, eq. (4).

    Parameters
    ----------
    points, normals, k, graph, n_jobs
        As in :func:`feature_intensity`.

    Returns
    -------
    (n, 3) ndarray
        Filtered unit normals ``n*_i``, oriented like the input normals.

    Notes
    -----
    Paper Section 4.1; docs/ALGORITHM.md step 3: spatial Gaussian of width ``r_i / 2`` times a
    Gaussian of the normal deviation angle whose width is that angle's standard deviation over
    the list.
    """
    run = _prepare(points, normals, k, graph, n_jobs)
    with threads(n_jobs):
        out = core.filter_normals(run.points, run.normals, run.graph)
    return run.unsort(out)
