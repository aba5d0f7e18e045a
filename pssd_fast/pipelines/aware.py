"""The feature-aware pipeline of the presets "default" and "fast" (docs/ALGORITHM.md, "The
feature-aware pipeline"; docs/DECISIONS.md, "Beyond the paper")."""
import time

import numpy as np

from .. import core
from .._validation import check_k
from ..graph import knn_graph

#: The noise-driven choice of ``k`` (preset "default"). A probe fit with ``probe_k``
#: neighbours measures the noise ``sigma`` (median RMS residual of the unweighted quadratic
#: fits) relative to the probe's mean list radius ``r``; ``k`` is interpolated, linearly in
#: ``log(sigma / r)`` and ``log k``, between the anchors ``(ratio, k)`` and held at the end
#: values outside them. Each anchor is the ratio the probe measures on the generated CAD part
#: (100,000 points) at 0.25%, 0.5% and 1% noise and the smallest ``k`` of the grid tried there
#: (48, 64, 96, 128, 160, 192) that beat both CGAL peers on both errors (docs/DECISIONS.md,
#: "Beyond the paper").
AUTO_K = {"probe_k": 96, "anchors": ((0.133, 64), (0.227, 96), (0.304, 160))}


def step(points, nrm, graph, lam, params, clock, last=True):
    """One feature-aware iteration once the graph and normals exist.

    Bilateral filter of the normals to ``n*_i``, a quadratic fitted in the frame of ``p_i`` and
    ``n*_i`` with each neighbour weighted by distance and normal agreement (``sigma_n``), and
    the projection ``p_i + g_i(0, 0) n*_i``. The move uses neither the likelihood nor the feature
    intensity; the last iteration still computes both (from the fit's RMS residual, and by the
    paper's voting at the paper's constants) so that every preset returns them.
    """
    filtered = clock.run("filter", core.filter_normals, points, nrm, graph)
    height, rms, degree = clock.run("mls", core.aware_fit, points, filtered, graph,
                                    params["sigma_n"])
    moved, held = clock.run("update", core.project, points, filtered, height)
    extra = None
    if last:
        lik, _ = clock.run("likelihood", core.sampling_likelihood, rms, "exp")
        paper = core.FEATURE_DEFAULTS
        feat, _ = clock.run("feature", core.feature_intensity, points, nrm, graph,
                            paper["radius_factor"] * core.mean_spacing(graph),
                            paper["delta"], paper["alpha"], paper["beta"])
        extra = (lik, feat)
    counts = np.bincount(degree, minlength=7)
    record = {"times": clock.times, "held_points": int(held.sum()),
              "mean_residual": float(rms.mean()),
              "fit_degree": {name: int(counts[code])
                             for name, code in core.AWARE_FIT_DEGREES.items()}}
    return moved, filtered, extra, record


def choose_k(points, given):
    """``k`` from the noise: a probe fit gives ``sigma`` and the list radius (:data:`AUTO_K`).

    Parameters
    ----------
    points : (n, 3) float64
        The input points (Morton order).
    given : (n, 3) float64 or None
        The caller's normals, else PCA normals are estimated on the probe graph.

    Returns
    -------
    k : int
    probe : dict
        What the probe measured (``noise``, ``probe_radius``, their ``ratio``), for ``stats``.
    graph : ListScales
        The probe's lists, which serve the first iteration when ``k`` is at most ``probe_k``.
    """
    started = time.perf_counter()
    n = points.shape[0]
    probe = min(AUTO_K["probe_k"], n - 1)
    graph = knn_graph(points, probe, False)
    if given is None:
        nrm, _ = core.pca_normals(points, graph, core.outward_hints(points))
    else:
        nrm = given
    filtered = core.filter_normals(points, nrm, graph)
    _, rms, _ = core.aware_fit(points, filtered, graph, 0.0)
    sigma = float(np.median(rms))
    radius = float(np.mean(graph.list_radius()))
    ratio = sigma / radius if radius > 0.0 else 0.0
    anchors = np.log(np.array(AUTO_K["anchors"], dtype=float))
    k = int(round(np.exp(np.interp(np.log(max(ratio, 1e-12)), anchors[:, 0], anchors[:, 1]))))
    k = max(min(k, n - 1), min(10, n - 1))
    scales = {"k": k, "probe_k": probe, "noise": sigma, "probe_radius": radius, "ratio": ratio,
              "seconds": time.perf_counter() - started}
    return check_k(k, n), scales, graph
