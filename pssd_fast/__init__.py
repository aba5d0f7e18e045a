"""pssd_fast: fast, feature-preserving denoising of point-sampled surfaces.

Numpy in, numpy out::

    import pssd_fast
    result = pssd_fast.denoise(points)          # points: (n, 3) array
    result.points, result.normals, result.feature_intensity

The stages of the method are public too (:func:`neighbors`, :func:`estimate_normals`,
:func:`mls_fit`, :func:`sampling_likelihood`, :func:`feature_intensity`,
:func:`filter_normals`, :func:`outlier_score`), so other tools can use them as a backend.
Kernels are compiled by numba on first use and cached on disk; :func:`warmup` compiles them
ahead of time. :mod:`pssd_fast.interop` converts the point clouds of Open3D, trimesh and
PDAL (structured arrays), which :func:`denoise` also takes as they are.

The subpackages load on first use, so that ``import pssd_fast`` stays cheap: ``pssd_fast.io``
(point-cloud files), ``pssd_fast.pictures`` (pictures of a cloud), ``pssd_fast.datasets``
(generated clouds with their truth) and ``pssd_fast.tiled`` (tiled runs on Dask).
"""
from . import interop  # noqa: F401 (pssd_fast.interop, loaded with the package)
from ._threads import configure_threads
from ._validation import DenoiseWarning
from .denoise import METHODS, denoise
from .graph import NeighborGraph, morton_order, neighbors
from .run import DenoiseResult
from .stages import (
    MLSFit, estimate_normals, feature_intensity, filter_normals, mls_fit, outlier_score,
    sampling_likelihood,
)
from .stats import Stats
from .warmup import warmup

__version__ = "0.1.0"

__all__ = [
    "METHODS", "DenoiseResult", "DenoiseWarning", "MLSFit", "NeighborGraph", "Stats",
    "configure_threads", "denoise", "estimate_normals", "feature_intensity", "filter_normals",
    "mls_fit", "morton_order", "neighbors", "outlier_score", "sampling_likelihood", "warmup",
]

#: Subpackages imported on first access (PEP 562), not by ``import pssd_fast``.
SUBPACKAGES = ("datasets", "io", "pictures", "tiled")


def __getattr__(name):
    if name in SUBPACKAGES:
        from importlib import import_module

        return import_module(f"{__name__}.{name}")  # which also binds it here
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(SUBPACKAGES))
