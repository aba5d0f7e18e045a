"""Per-point fields for pictures, in the units the pictures use: read from a cloud or computed.

Two kinds of fields exist. ``likelihood`` and ``feature`` (``feature_intensity``) are what
:func:`pssd_fast.denoise` returns and ``pssd denoise`` stores, so a cloud that lacks them gets
them by exactly that run: a raw scan and its denoised file show the same values.
``curvature`` and ``displacement`` describe the drawn points themselves and are scaled by the
drawn cloud's bounding-box diagonal, so that pictures of one object before and after denoising
share a scale whatever its size.
"""
import numpy as np

from .._validation import as_points

__all__ = ["CURVATURE_K", "FIELDS", "STORED", "curvature", "diagonal", "field_values"]

#: Fields :func:`field_values` returns.
FIELDS = ("likelihood", "feature", "curvature", "displacement")
#: Name under which ``pssd denoise`` stores each field it writes.
STORED = {"likelihood": "likelihood", "feature": "feature_intensity",
          "displacement": "displacement"}
#: Neighbours of the MLS fits behind :func:`curvature` (the paper's ``k``): fixed, not taken
#: from the noise, so that a noisy cloud and its denoised copy are measured alike.
CURVATURE_K = 25


def diagonal(points):
    """Length of the bounding-box diagonal of ``points`` (1 for a single location)."""
    pts, _ = as_points(points)
    length = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    return length if length > 0.0 else 1.0


def curvature(points, *, n_jobs=None):
    """Mean curvature of each point's MLS cubic, times the bounding-box diagonal.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates, at least ``CURVATURE_K + 1`` points.
    n_jobs : int, optional
        Threads, as for :func:`pssd_fast.denoise`.

    Returns
    -------
    (n,) float64
        ``H * diagonal``, dimensionless: a sphere reads ``2 * sqrt(3) = 3.46`` everywhere (its
        sign follows the normals' orientation).

    Notes
    -----
    The fits use PCA normals oriented away from the centroid (:func:`pssd_fast.mls_fit`
    without normals), never a file's stored normals: those differ between a raw scan and its
    denoised copy, and the measure must not.
    """
    from ..graph import neighbors
    from ..stages import mls_fit

    pts, _ = as_points(points)
    graph = neighbors(pts, k=CURVATURE_K, n_jobs=n_jobs)
    return mls_fit(pts, graph=graph, n_jobs=n_jobs).curvature * diagonal(pts)


def field_values(name, points, normals=None, stored=None, *, progress=None, **denoise_options):
    """The values of field ``name`` for a cloud, as ``pssd render`` draws them.

    Parameters
    ----------
    name : {"likelihood", "feature", "curvature", "displacement"}
        The field.
    points : array_like, shape (n, 3)
        The cloud's coordinates.
    normals : array_like, shape (n, 3), optional
        The cloud's stored normals; passed to :func:`pssd_fast.denoise` like ``pssd denoise``
        does (used by its first iteration).
    stored : mapping of str to (n,) array_like, optional
        The cloud's per-point attributes (:attr:`pssd_fast.io.PointCloud.fields`).
        ``likelihood``, ``feature_intensity`` and ``displacement`` are taken from it when
        present.
    progress : bool or callable, optional
        Progress of a denoise run, as for :func:`pssd_fast.denoise`.
    **denoise_options
        ``iterations``, ``k``, ``lam``, ``preset``, ``rebuild_graph``, ``n_jobs``, ... of the
        :func:`pssd_fast.denoise` run that computes a missing ``likelihood`` or ``feature``
        (``method`` is always "robust"). Give the options ``pssd denoise`` was given to get
        the values it stores.

    Returns
    -------
    (n,) float64
        ``likelihood`` and ``feature``: as stored, else the result of ``denoise(points,
        normals, **denoise_options)`` rounded to float32 as ``pssd denoise`` stores it, in
        ``[0, 1]``. ``curvature``: :func:`curvature` of the
        points (never read from the cloud). ``displacement``: the stored displacement divided by
        the bounding-box diagonal.

    Raises
    ------
    ValueError
        For an unknown ``name``, a ``displacement`` the cloud does not hold, a stored field of
        the wrong length, or bad denoise options.
    """
    from ..denoise import denoise

    if name not in FIELDS:
        raise ValueError(f"unknown field {name!r}; choose one of {', '.join(FIELDS)}")
    pts, _ = as_points(points)
    n = pts.shape[0]
    stored = stored or {}
    if name == "curvature":
        return curvature(pts, n_jobs=denoise_options.get("n_jobs"))
    key = STORED[name]
    if key in stored:
        values = np.asarray(stored[key], dtype=np.float64)
        if values.shape != (n,):
            raise ValueError(f"stored {key} has shape {values.shape}; expected ({n},)")
        return values / diagonal(pts) if name == "displacement" else values
    if name == "displacement":
        raise ValueError("the cloud holds no displacement; render the output of pssd denoise, "
                         "which stores it")
    result = denoise(pts, normals, progress=progress, **denoise_options)
    # Rounded as pssd denoise stores its added fields (float32), so both pictures agree.
    return getattr(result, key).astype(np.float32).astype(np.float64)
