"""Compile (or load from numba's on-disk cache) every kernel before timed work, or the longest
to compile in a process of its own while the caller's run compiles the rest."""
import subprocess
import sys
import time
import warnings
from types import SimpleNamespace

import numpy as np

from . import core, regions
from ._validation import DenoiseWarning
from .denoise import METHODS, denoise
from .graph import GRID_K, RADIX_POINTS, code_order, inside_boxes, knn_graph
from .jit import cache
from .stages import outlier_score


def warmup():
    """Compile every kernel on a tiny cloud, so later calls run at full speed.

    A call compiles only the kernels it needs; ``warmup`` compiles all of them (about a minute
    on 2 cores from an empty cache) and stores them in the kernel cache (docs/architecture.md, "The
    kernel cache"), so that no later process compiles: run it when building a container image or
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
    with warnings.catch_warnings():
        # The cloud is small on purpose: the runs' note that it is is not the caller's.
        warnings.simplefilter("ignore", DenoiseWarning)
        _runs(points)
    outlier_score(points, k=10)
    # The halo tests of tiled runs and of the refinement.
    inside_boxes(points, regions.boxes(points))
    regions.near(points, points[:3], 0.5)
    # Lists as long as the baselines' at scan sizes come from the grid query.
    sphere = rng.normal(size=(GRID_K + 1, 3))
    knn_graph(sphere / np.linalg.norm(sphere, axis=1)[:, None], GRID_K, False)
    # Long clouds' Morton codes are sorted by radix.
    code_order(np.zeros(RADIX_POINTS, np.uint64))
    return time.perf_counter() - started


def _runs(points):
    """The runs of :func:`warmup`: every method and preset on ``points``."""
    for method in METHODS:
        denoise(points, method=method, k=10, iterations=1)
    denoise(points, k=10, iterations=1, preset="paper")
    # Two passes of a baseline on one graph: the second re-sorts the first's lists.
    denoise(points, method="mls", k=10, iterations=2, rebuild_graph=False)
    # The default method with and without given normals, and a float32 cloud.
    denoise(points.astype(np.float32), points, iterations=1)
    denoise(points, iterations=1, orient="outward")
    denoise(points, iterations=1, preset="fast")


def compile_ahead():
    """Start compiling the default method's feature-aware fit, the kernel that takes longest to
    compile (about a third of a first run's compiling), in a process of its own: the caller's
    run compiles the kernels it needs before that fit meanwhile, then loads the fit from the
    kernel cache (a process that needs a kernel another is compiling waits for it,
    :mod:`pssd_fast.jit.cache`). Only where the cache is kept on disk and holds no compiled
    kernel yet (a first run); else nothing starts.

    Returns
    -------
    subprocess.Popen or None
        The process (wait for it before exiting), or None.
    """
    folder = cache.cache_folder()
    if folder is None or not cache.stats()["persistent"] or any((folder / "built").glob("*")):
        return None
    return subprocess.Popen([sys.executable, "-c", "from pssd_fast.warmup import fits; fits()"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def fits():
    """Compile (or load) the feature-aware fit's kernel for the argument types every run of the
    default method calls it with, on a cloud of 16 points."""
    points = np.random.default_rng(0).normal(size=(16, 3))
    normals = points / np.linalg.norm(points, axis=1)[:, None]
    order = np.argsort(np.linalg.norm(points[:, None] - points[None], axis=2), axis=1)
    lists = SimpleNamespace(indptr=np.arange(0, 16 * 16 + 1, 16, dtype=np.int64),
                            indices=order.astype(np.int32).ravel())
    core.own_fits(points, normals, lists, 0.3)
