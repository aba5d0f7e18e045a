"""Compile (or load from numba's on-disk cache) every kernel before timed work."""
import time

import numpy as np

from .denoise import METHODS, denoise
from .graph import GRID_K, knn_graph
from .stages import outlier_score


def warmup():
    """Compile every kernel on a tiny cloud, so later calls run at full speed.

    A call compiles only the kernels it needs; ``warmup`` compiles all of them (about a minute
    on 2 cores from an empty cache) and stores them in the kernel cache (see the README, "How
    it works"), so that no later process compiles: run it when building a container image or
    on each machine type of a cluster. With the cache warm it only loads them (under a second).

    Returns
    -------
    float
        Seconds spent.
    """
    started = time.perf_counter()
    rng = np.random.default_rng(0)
    points = rng.normal(size=(64, 3))
    points /= np.linalg.norm(points, axis=1)[:, None]
    for method in METHODS:
        denoise(points, method=method, k=10, iterations=1)
    denoise(points, k=10, iterations=1, preset="paper")
    # Two passes of a baseline on one graph: the second re-sorts the first's lists.
    denoise(points, method="mls", k=10, iterations=2, rebuild_graph=False)
    # The default method with and without given normals, and a float32 cloud.
    denoise(points.astype(np.float32), points, iterations=1)
    denoise(points, iterations=1, orient="outward")
    denoise(points, iterations=1, preset="fast")
    outlier_score(points, k=10)
    # Lists as long as the baselines' at scan sizes come from the grid query.
    sphere = rng.normal(size=(GRID_K + 1, 3))
    knn_graph(sphere / np.linalg.norm(sphere, axis=1)[:, None], GRID_K, False)
    return time.perf_counter() - started
