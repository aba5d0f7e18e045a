"""The array layer: each stage on validated float64 arrays, without checks or copies.

The pipelines (:mod:`pssd_fast.pipelines`) and the public stage functions
(:mod:`pssd_fast.stages`) call these; they allocate the outputs, run one kernel and return plain
arrays. Inputs are trusted: C-contiguous float64 points and normals, and a
:class:`~pssd_fast.graph.NeighborGraph` of the same points. Not public API.
"""
from typing import NamedTuple

import numpy as np

from . import kernels
from ._validation import on_surface, surface_mean

#: ``likelihood`` forms of docs/ALGORITHM.md and their kernel codes.
LIKELIHOOD_FORMS = {"exp": kernels.likelihood.EXP, "ratio": kernels.likelihood.RATIO,
                    "residual": kernels.likelihood.RESIDUAL}
#: Length of the list prefix used to grow ``N_R`` (the paper's 9 nearest neighbours).
GROW_NEIGHBOURS = 9
#: The paper's constants of the feature intensity (``R = radius_factor * |E|``; eq. (3)).
FEATURE_DEFAULTS = {"radius_factor": 10.0, "delta": 0.2, "alpha": 0.3, "beta": 0.3}
#: Fit degree codes of :class:`~pssd_fast.stages.MLSFit` ``degree``.
FIT_DEGREES = {"cubic": kernels.mls.CUBIC, "quadratic": kernels.mls.QUADRATIC,
               "plane": kernels.mls.PLANE}
#: Fit codes of the feature-aware fit (number of coefficients fitted).
AWARE_FIT_DEGREES = {"quadratic": 6, "plane": 3, "mean_height": 1, "none": 0}
# No rows, no entries: :func:`kernels.mls.aware_fit` keeps no coefficients, or no leverage.
_NO_COEF = np.empty((0, 7))
_NO_LEVERAGE = np.empty(0)


def default_h(graph, h=None):
    """MLS width: ``h`` when given, else the mean list radius ``r_i`` of the points on the
    surface, those whose lists reach at most ``STRAY`` times the median radius (one point far
    from the rest would set the mean alone); 1 if every list is a single location."""
    if h is not None:
        return h
    h = surface_mean(graph.list_radius())
    return h if h > 0.0 else 1.0


def mean_spacing(graph):
    """``|E|``: mean distance from each point to its nearest other point, over the points on
    the surface (as :func:`default_h`)."""
    return surface_mean(graph.list_radius(), of=graph.nearest_distance())


def outward_hints(points):
    """Orientation hints pointing away from the cloud's centroid (deterministic, outward for
    star-shaped objects)."""
    return points - points.mean(axis=0)


#: List entries (the point itself included) over which orientation propagates: enough to
#: connect a sampled surface, few enough not to bridge close sheets (and to keep it cheap).
ORIENT_NEIGHBOURS = 10
#: Neighbours of the outlier score and its thresholds (docs/DECISIONS.md, "Outliers"): the
#: list radius over its median, the offset from the neighbours' plane over its median, and
#: that offset over the neighbours' own median distance to their plane (an edge's or a
#: corner's neighbours lie far from any one plane, so its points are not outliers).
OUTLIER_K = 64
OUTLIER_RADIUS_RATIO = 2.0
OUTLIER_OFFSET_RATIO = 6.0
OUTLIER_SPREAD_RATIO = 3.0
#: Floor of the outlier score's scales, relative to the bounding-box diagonal (exact clouds).
OUTLIER_SCALE_FLOOR = 1e-9


def orient_normals(points, nrm, graph, orient):
    """``nrm`` (unit, any signs) made consistent by propagation, in place, then each connected
    component turned as a whole towards ``orient``: ``"outward"``, ``"up"`` or a viewpoint.

    A component is flipped when the sum of ``n_i . d_i`` over its points is negative, ``d_i``
    being ``p_i`` minus the cloud's centroid (outward), ``+z`` (up) or the viewpoint minus
    ``p_i``. For a closed surface sampled uniformly the outward sum is ``3 V / density`` (the
    divergence theorem) whatever the centroid, so the vote cannot be fooled by its shape.
    Returns the number of components.
    """
    component = np.empty(points.shape[0], np.int64)
    count = kernels.orient.propagate_orientation(graph.indptr, graph.indices,
                                                 ORIENT_NEIGHBOURS, nrm, component)
    if isinstance(orient, str) and orient == "up":
        agree = nrm[:, 2]
    elif isinstance(orient, str):
        agree = np.einsum("ij,ij->i", nrm, points - points.mean(axis=0))
    else:
        agree = np.einsum("ij,ij->i", nrm, orient - points)
    vote = np.bincount(component, weights=agree, minlength=count)
    nrm *= np.where(vote[component] < 0.0, -1.0, 1.0)[:, None]
    nrm += 0.0  # -0 to 0: a normal turned twice here ends as one left alone pointwise
    return count


def orient_pointwise(points, nrm, orient, centroid):
    """``nrm`` (in place) each turned on its own towards ``orient``: ``"up"`` (``+z``),
    ``"outward"`` (away from ``centroid``) or a viewpoint."""
    if isinstance(orient, str) and orient == "up":
        agree = nrm[:, 2]
    elif isinstance(orient, str):
        agree = np.einsum("ij,ij->i", nrm, points - centroid)
    else:
        agree = np.einsum("ij,ij->i", nrm, orient - points)
    nrm *= np.where(agree < 0.0, -1.0, 1.0)[:, None]
    nrm += 0.0  # -0 to 0, as orient_normals leaves them


def outlier_score(points, graph):
    """Per-point outlier score: flagged where it exceeds 1 (docs/DECISIONS.md, "Outliers").

    The larger of two ratios: the list radius (distance to the farthest of the ``k``
    neighbours) over ``OUTLIER_RADIUS_RATIO`` times its median over the cloud, and the
    distance to the plane of the other list members over the larger of
    ``OUTLIER_OFFSET_RATIO`` times its median and ``OUTLIER_SPREAD_RATIO`` times those members'
    own median distance to their plane. The first catches points far from everything, the second
    points just off the surface, but not where the surface itself bends away from one plane
    (sharp edges, corners). Medians are floored at ``OUTLIER_SCALE_FLOOR`` times the
    bounding-box diagonal, so that exact (noise-free) samples keep finite scores.
    """
    offsets, spreads = np.empty(points.shape[0]), np.empty(points.shape[0])
    kernels.outliers.plane_offsets(points, graph.indptr, graph.indices, offsets, spreads)
    radius = graph.list_radius()
    extent = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    floor = max(OUTLIER_SCALE_FLOOR * extent, np.finfo(np.float64).tiny)
    off = np.maximum(OUTLIER_OFFSET_RATIO * max(float(np.median(offsets)), floor),
                     OUTLIER_SPREAD_RATIO * spreads)
    return np.maximum(radius / (OUTLIER_RADIUS_RATIO * max(float(np.median(radius)), floor)),
                      offsets / off)


def pca_normals(points, graph, hints):
    """PCA normals oriented along ``hints``, and the mask of degenerate neighbourhoods."""
    out = np.empty_like(points)
    degenerate = np.empty(points.shape[0], np.bool_)
    kernels.normals.pca_normals(points, graph.indptr, graph.indices, hints, out, degenerate)
    return out, degenerate


class ListPlanes(NamedTuple):
    """Outputs of :func:`list_planes`, one row per point (see
    ``kernels.normals.list_planes``)."""

    centres: np.ndarray
    normals: np.ndarray
    variation: np.ndarray
    spread: np.ndarray

    @property
    def degenerate(self):
        """Where the list has no plane, as :func:`pca_normals` reports it."""
        return np.isinf(self.variation)


def list_planes(points, graph, hints):
    """The PCA plane of every list: :func:`pca_normals`' normals (oriented along ``hints``),
    with the centroids, surface variations and RMS spreads :func:`shifted_normals` reads."""
    n = points.shape[0]
    planes = ListPlanes(np.empty_like(points), np.empty_like(points), np.empty(n), np.empty(n))
    kernels.normals.list_planes(points, graph.indptr, graph.indices, hints, *planes)
    return planes


def shifted_normals(points, nrm, graph, planes, candidates, tolerance):
    """Each point's normal from the flattest of the list ``planes`` (:func:`list_planes` of
    ``graph``), among those of its first ``candidates`` neighbours, that passes within
    ``tolerance`` of that list's RMS spread of the point; signed like ``nrm`` (its own normal
    where none qualifies)."""
    out = np.empty_like(points)
    kernels.normals.shifted_normals(points, graph.indptr, graph.indices, nrm, *planes,
                                    candidates, tolerance, out)
    return out


def local_noise(points, graph, lengths):
    """What the noise probe reads at each point (``kernels.noise.local_noise``): the robust
    spread of its neighbours about their quadratic and the list radius, for each prefix of
    ``lengths`` of ``graph``'s equal-length lists; two ``(n, len(lengths))`` arrays."""
    n = points.shape[0]
    scale = np.empty((n, lengths.shape[0]))
    radius = np.empty((n, lengths.shape[0]))
    kernels.noise.local_noise(points, graph.indices.reshape(n, -1), lengths, scale, radius)
    return scale, radius


def mls_fit(points, nrm, graph, h):
    """MLS cubic of every point: projections, residuals, fitted degree, mean curvature."""
    n = points.shape[0]
    proj = np.empty_like(points)
    resid = np.empty(n)
    degree = np.empty(n, np.int8)
    curvature = np.empty(n)
    kernels.mls.mls_fit(points, nrm, graph.indptr, graph.indices, h, proj, resid, degree,
                        curvature)
    return proj, resid, degree, curvature


def aware_fit(points, nrm, graph, sigma_n, mass=None, robust=False):
    """Feature-aware quadratic of every point in the frame of ``nrm``: height of the surface
    above the point, RMS residual and number of coefficients fitted. ``mass``: a factor on
    each point's weight, or None; ``robust``: try the robust fit that keeps the sides of a
    thin wall apart."""
    n = points.shape[0]
    height = np.empty(n)
    rms = np.empty(n)
    degree = np.empty(n, np.int8)
    mass = np.empty(0) if mass is None else mass
    kernels.mls.aware_fit(points, points, nrm, mass, graph.indptr, graph.indices, sigma_n,
                          robust, height, rms, degree, _NO_COEF, _NO_LEVERAGE)
    return height, rms, degree


def surface_fits(surface, nrm, lists, sigma_n, mass=None):
    """Feature-aware quadratic of each ``surface`` point's lists (unit normals ``nrm``; each
    neighbour's weight times its ``mass`` if given), kept for :func:`evaluate_fits`:
    coefficients and inverse list radius ``(m, 7)``, RMS residual, degree."""
    m = surface.shape[0]
    rms = np.empty(m)
    degree = np.empty(m, np.int8)
    coef = np.empty((m, 7))
    kernels.mls.aware_fit(surface, surface, nrm, np.empty(0) if mass is None else mass,
                          lists.indptr, lists.indices, sigma_n, False, np.empty(m), rms, degree,
                          coef, _NO_LEVERAGE)
    return coef, rms, degree


def own_fits(points, nrm, lists, sigma_n, origins=None):
    """:func:`aware_fit` with its robust alternative on lists that start with the point
    itself: the height, RMS residual, degree, and the plain fit's leverage on the point.
    ``origins``: the points whose lists of ``points`` these are, where not ``points`` (each
    list starting with a copy of its origin)."""
    origins = points if origins is None else origins
    n = origins.shape[0]
    height, rms, leverage = np.empty(n), np.empty(n), np.empty(n)
    degree = np.empty(n, np.int8)
    kernels.mls.aware_fit(origins, points, nrm, np.empty(0), lists.indptr, lists.indices,
                          sigma_n, True, height, rms, degree, _NO_COEF, leverage)
    return height, rms, degree, leverage


def evaluate_fits(points, surface, nrm, coef, nearest, distance):
    """Each point moved onto the fits ``coef`` of its ``nearest`` surface points (at
    ``distance``; rows past the surface's are none), along their normals, by the
    inverse-distance-weighted mean of those steps; and which points stayed because no step
    was finite and within its fit's support."""
    moved = np.empty_like(points)
    held = np.empty(points.shape[0], np.bool_)
    kernels.mls.evaluate_fits(points, surface, nrm, coef, nearest, distance, moved, held)
    return moved, held


def project(points, nrm, height, support):
    """``p_i + height_i n_i`` for unit normals ``nrm``; a point whose step is not finite, or
    longer than its ``support`` (the radius of the list its fit was made over), stays where it
    is (docs/DECISIONS.md, "No point flung"). Returns the points and the mask of those held."""
    step = height[:, None] * nrm
    held = ~(np.abs(height) <= support) | ~np.isfinite(step).all(axis=1)
    step[held] = 0.0
    return points + step, held


def hold_unsupported(points, moved, support, held=None):
    """``moved`` (in place) with each point that moved farther from ``points`` than its
    ``support`` (the radius of the list behind its move), or not to a finite place, put back,
    and each point whose support reaches more than ``STRAY`` times the median, which lies off
    the surface (a stray return: its list is the surface far away); and the mask of the points
    held, those of ``held`` included (docs/DECISIONS.md, "No point flung", "Stray points")."""
    far = ~(np.sqrt(np.einsum("ij,ij->i", moved - points, moved - points)) <= support)
    far |= ~on_surface(support)
    moved[far] = points[far]
    return moved, far if held is None else far | held


def sampling_likelihood(resid, form, dbar=None):
    """Eq. (2) in the chosen ``form``, and the mean residual ``dbar`` it is relative to (by
    default the mean of ``resid``; a tile of a cloud takes the whole cloud's)."""
    dbar = float(np.mean(resid)) if dbar is None else dbar
    out = np.empty_like(resid)
    kernels.likelihood.sampling_likelihood(resid, dbar, LIKELIHOOD_FORMS[form], out)
    return out, dbar


def feature_intensity(points, nrm, graph, radius, delta, alpha, beta):
    """Eq. (3) over the region-grown ``N_R`` of radius ``radius``, and each region's size."""
    n = points.shape[0]
    out = np.empty(n)
    size = np.empty(n, np.int64)
    kernels.feature.feature_intensity(points, nrm, graph.indptr, graph.indices, radius,
                                      GROW_NEIGHBOURS, delta, alpha, beta, out, size)
    return out, size


def filter_normals(points, nrm, graph):
    """Bilateral filter of the normals, eq. (4)."""
    out = np.empty_like(points)
    kernels.bilateral.filter_normals(points, nrm, graph.indptr, graph.indices, out)
    return out


def filter_points(points, nrm, graph, sigma_c, sigma_s):
    """The BIL baseline: each point moved along its normal by the bilateral mean height
    (``sigma_c``, ``sigma_s`` 0: per-point defaults)."""
    out = np.empty_like(points)
    kernels.bilateral.filter_points(points, nrm, graph.indptr, graph.indices, sigma_c, sigma_s,
                                    out)
    return out


def move(points, proj, filtered, lik, feat, lam):
    """The paper's update ``p_i + m_i |q_i - p_i| n*_i``, and the mask of points held in place
    because their step was not finite."""
    out = np.empty_like(points)
    held = np.empty(points.shape[0], np.bool_)
    kernels.update.move_points(points, proj, filtered, lik, feat, lam, out, held)
    return out, held


def cell_means(points, normals, order, starts, mass=None):
    """Mean point of each group of :func:`pssd_fast.graph.cell_order`, and the unit mean
    of its ``normals`` (each turned to the side of the group's first; None without ``normals``),
    each point weighted by its ``mass`` if given. The sums run in ``order``, so the result does not
    depend on the thread count."""
    m = starts.shape[0] - 1
    means = np.empty((m, 3))
    mean_normals = np.empty((m, 3))
    kernels.cells.cell_means(points, np.empty((0, 3)) if normals is None else normals,
                             np.empty(0) if mass is None else mass, order, starts, means,
                             mean_normals)
    return means, None if normals is None else mean_normals


def relative_rows(points, order, centre):
    """``points[order] - centre``, a new C-contiguous array."""
    out = np.empty((order.shape[0], 3))
    kernels.order.gather_rows(points, order, centre, out)
    return out


def caller_order(values, order):
    """``values`` (row ``i`` belonging to input row ``order[i]``) back in the input's order."""
    out = np.empty_like(values)
    if values.ndim == 1:
        out[order] = values
    else:
        kernels.order.scatter_rows(values, order, np.zeros(values.shape[1]), out)
    return out
