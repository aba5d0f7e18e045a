"""What the iterations of :func:`pssd_fast.denoise` take from the input besides the points:
the outlier score and the signs of the estimated normals."""
import time

import numpy as np

from . import core
from .graph import knn_graph, morton_order, truncate_graph
from .kernels.order import gather_rows


def estimated_normals(points, graph, previous, orient, centre):
    """PCA normals signed like the ``previous`` iteration's, else by ``orient`` (propagation)
    or away from the centroid (``orient=None``); ``points`` are relative to ``centre``."""
    hints = core.outward_hints(points) if previous is None else previous
    nrm, degenerate = core.pca_normals(points, graph, hints)
    if orient is not None:
        core.orient_normals(points, nrm, graph, orient if isinstance(orient, str)
                            else orient - centre)
    return nrm, degenerate


def outlier_score(points, presorted=False, probe=None):
    """:func:`pssd_fast.core.outlier_score` of ``points`` and the seconds spent.

    ``points`` in the caller's order are sorted along a Morton curve (and centred) for the
    query, and the score comes back in their order. ``presorted`` points are already sorted
    and centred; ``probe``, lists of at least ``OUTLIER_K`` entries of them, spares the query.
    """
    started = time.perf_counter()
    n = points.shape[0]
    k = min(core.OUTLIER_K, n - 1)
    if not presorted:
        order = morton_order(points)
        current = np.empty_like(points)
        gather_rows(points, order, 0.5 * (points.min(axis=0) + points.max(axis=0)), current)
        score = np.empty(n)
        score[order] = outlier_score(current, True)[0]
        return score, time.perf_counter() - started
    if probe is not None and probe.indices.shape[0] >= k * n:
        graph = truncate_graph(probe, points, k)
    else:
        graph = knn_graph(points, k, False)
    return core.outlier_score(points, graph), time.perf_counter() - started
