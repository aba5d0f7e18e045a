"""The feature-aware fit of the default method's points (docs/ALGORITHM.md, "The feature-aware
fit"; docs/DECISIONS.md, "Beyond the paper"), the paper's voting that the default method gives
on request, and the noise probe behind the baselines' ``k``."""
import time

import numpy as np

from .. import core
from .._validation import check_k
from ..graph import knn_graph

#: The noise-driven choice of the baselines' ``k`` (``method="bilateral"`` or ``"mls"`` under
#: preset "default"). A probe fit with ``probe_k``
#: neighbours measures the noise ``sigma`` (median RMS residual of the unweighted quadratic
#: fits) relative to the probe's mean list radius ``r``; ``k`` is interpolated, linearly in
#: ``log(sigma / r)`` and ``log k``, between the anchors ``(ratio, k)`` and held at the end
#: values outside them. Each anchor is the ratio the probe measures on the generated CAD part
#: (100,000 points) at 0.25%, 0.5% and 1% noise and the smallest ``k`` of the grid tried there
#: (48, 64, 96, 128, 160, 192) that beat both CGAL peers on both errors (docs/DECISIONS.md,
#: "Beyond the paper").
AUTO_K = {"probe_k": 96, "anchors": ((0.133, 64), (0.227, 96), (0.304, 160))}
#: The probe fits at most this many points: a larger cloud is probed on every ``s``-th point of
#: its Morton order (an evenly spread subsample), its list radius scaled by ``sqrt(1 / s)`` as on
#: a surface.
PROBE_POINTS = 100_000


def interpolated_k(x, anchors):
    """``k`` at ``x``, linear in ``log x`` and ``log k`` between the ``(x, k)`` ``anchors``
    and held at the end values outside them (rounded)."""
    logs = np.log(np.array(anchors, dtype=float))
    return int(round(np.exp(np.interp(np.log(max(x, 1e-12)), logs[:, 0], logs[:, 1]))))


def fit_and_move(points, nrm, graph, sigma_n, clock, mass=None):
    """One feature-aware move: the normals ``nrm`` filtered (eq. (4)), a quadratic fitted in
    the frame of each point and its filtered normal, its neighbours weighted by distance and
    normal agreement (``sigma_n``; times ``mass`` if given), with the robust alternative that
    keeps a thin wall's sides apart (not where ``mass`` is given: cell means have averaged the
    sides already, and there it only costs accuracy; docs/DECISIONS.md, "Thin walls"), and the
    projection along the filtered normal. Returns the moved points, the filtered normals, the
    fit's RMS residual and degree, and the points held in place (their step was not finite, or
    longer than the radius of the list it was fitted over)."""
    filtered = clock.run("filter", core.filter_normals, points, nrm, graph)
    height, rms, degree = clock.run("mls", core.aware_fit, points, filtered, graph, sigma_n,
                                    mass, mass is None)
    moved, held = clock.run("update", core.project, points, filtered, height,
                            graph.list_radius())
    return moved, filtered, rms, degree, held


def region_radius(spacing):
    """``R`` of the paper's voting, from the mean spacing ``|E|``, at the paper's constant."""
    return core.FEATURE_DEFAULTS["radius_factor"] * spacing


def voted_feature(points, nrm, graph, radius):
    """Feature intensity by the paper's voting at the paper's thresholds over ``N_R``."""
    paper = core.FEATURE_DEFAULTS
    return core.feature_intensity(points, nrm, graph, radius, paper["delta"], paper["alpha"],
                                  paper["beta"])[0]


def step_record(times, held, rms_sum, n, degree_counts):
    """An iteration's record for ``stats``, from its counts and sums."""
    return {"times": times, "held_points": int(held), "mean_residual": float(rms_sum / n),
            "fit_degree": {name: int(degree_counts[code])
                           for name, code in core.AWARE_FIT_DEGREES.items()}}


def choose_k(points, given, probe_points=PROBE_POINTS, probe_k=AUTO_K["probe_k"]):
    """``k`` from the noise: a probe fit gives ``sigma`` and the list radius (:data:`AUTO_K`).

    Parameters
    ----------
    points : (n, 3) float64
        The input points (Morton order).
    given : (n, 3) float64 or None
        The caller's normals, else PCA normals are estimated on the probe graph.
    probe_points : int
        The most points the probe fits (an evenly spread subsample of larger clouds).
    probe_k : int
        Neighbours of each probe fit; the anchors of :data:`AUTO_K` hold for its default.

    Returns
    -------
    k : int
    probe : dict
        What the probe measured (``noise``, ``probe_radius``, their ``ratio``), for ``stats``.
    graph : ListScales or None
        The probe's lists, which serve the first iteration when ``k`` is at most ``probe_k``;
        None when the probe ran on a subsample.
    """
    started = time.perf_counter()
    n = points.shape[0]
    stride = -(-n // probe_points)
    sigma, radius, probe, graph = _probe(points, given, stride, probe_k)
    ratio = sigma / radius if radius > 0.0 else 0.0
    k = interpolated_k(ratio, AUTO_K["anchors"])
    k = max(min(k, n - 1), min(10, n - 1))
    scales = {"k": k, "probe_k": probe, "probe_points": -(-n // stride), "probe_stride": stride,
              "noise": sigma, "probe_radius": radius, "ratio": ratio,
              "seconds": time.perf_counter() - started}
    return check_k(k, n), scales, graph if stride == 1 else None


def _probe(points, given, stride, probe_k):
    """Median RMS residual of unweighted quadratics over ``probe_k`` neighbours of every
    ``stride``-th point, the lists' mean radius scaled to the whole cloud, ``probe_k`` and the
    lists."""
    sample = np.ascontiguousarray(points[::stride])
    probe = min(probe_k, sample.shape[0] - 1)
    graph = knn_graph(sample, probe, False)
    if given is None:
        nrm, _ = core.pca_normals(sample, graph, core.outward_hints(sample))
    else:
        nrm = np.ascontiguousarray(given[::stride])
    filtered = core.filter_normals(sample, nrm, graph)
    _, rms, _ = core.aware_fit(sample, filtered, graph, 0.0)
    return (float(np.median(rms)), float(np.mean(graph.list_radius())) / np.sqrt(stride), probe,
            graph)
