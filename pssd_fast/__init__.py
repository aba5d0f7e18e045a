"""pssd_fast: fast, feature-preserving denoising of point-sampled surfaces.

Numpy in, numpy out::

    import pssd_fast
    result = pssd_fast.denoise(points)          # points: (n, 3) array
    result.points, result.normals, result.feature_intensity

The stages of the method are public too (:func:`neighbors`, :func:`estimate_normals`,
:func:`mls_fit`, :func:`sampling_likelihood`, :func:`feature_intensity`,
:func:`filter_normals`, :func:`outlier_score`), so other tools can use them as a backend.
Kernels are compiled by numba on first use and cached on disk; :func:`warmup` compiles them
ahead of time.
"""
import os

# pykdtree and numba's kernels each bring their own OpenMP (libgomp) thread pool. An idle pool
# spins for 300,000 rounds before it sleeps, holding the cores the other pool's next call
# needs: a quarter of a run at 30,000 points (docs/DECISIONS.md, "Scan sizes: one fit per
# surface point, and two thread pools"). Each pool reads this when it loads; a wait policy the
# caller chose is left as it is.
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "10000")

from .denoise import METHODS, DenoiseResult, denoise  # noqa: E402 (after the setting)
from .graph import NeighborGraph, morton_order, neighbors
from .stages import (
    MLSFit, estimate_normals, feature_intensity, filter_normals, mls_fit, outlier_score,
    sampling_likelihood,
)
from .warmup import warmup

__version__ = "0.1.0"

__all__ = [
    "METHODS", "DenoiseResult", "MLSFit", "NeighborGraph", "denoise", "estimate_normals",
    "feature_intensity", "filter_normals", "mls_fit", "morton_order", "neighbors",
    "outlier_score", "sampling_likelihood", "warmup",
]
