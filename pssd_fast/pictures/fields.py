"""Per-point fields for pictures, in the units the pictures use: read from a cloud or computed.

Three kinds of fields exist. ``likelihood`` and ``feature`` (``feature_intensity``) are what
:func:`pssd_fast.denoise` returns and ``pssd denoise`` stores, so a cloud that lacks them gets
them by exactly that run: a raw scan and its denoised file show the same values.
``curvature`` describes the drawn points themselves and is scaled by the drawn cloud's
bounding-box diagonal, so that pictures of one object before and after denoising share a scale
whatever its size. ``displacement``, ``classification``, ``intensity`` and ``rgb`` (``red``,
``green``, ``blue``) are read from the cloud as they are, in its units (:func:`units`).
"""
import re

import numpy as np

from .._validation import as_points
from .colours import rgb_colours

__all__ = ["CURVATURE_K", "FIELDS", "FROM_CLOUD", "STORED", "colourings", "curvature", "diagonal",
           "field_values", "units"]

#: Fields :func:`field_values` returns.
FIELDS = ("likelihood", "feature", "curvature", "displacement", "classification", "intensity",
          "rgb")
#: Name under which a cloud holds each field (``pssd denoise`` stores the first three).
STORED = {"likelihood": ("likelihood",), "feature": ("feature_intensity",),
          "displacement": ("displacement",), "classification": ("classification",),
          "intensity": ("intensity",), "rgb": ("red", "green", "blue")}
#: Neighbours of the MLS fits behind :func:`curvature` (the paper's ``k``): fixed, not taken
#: from the noise, so that a noisy cloud and its denoised copy are measured alike.
CURVATURE_K = 25
#: Fields only the cloud can give (likelihood and feature are computed where missing).
FROM_CLOUD = ("displacement", "classification", "intensity", "rgb")
# Linear units of LAS coordinate systems: GeoTIFF unit codes (EPSG) and WKT factors to metres.
_EPSG_UNITS = {9001: "m", 9002: "ft", 9003: "US ft"}
_WKT_UNITS = ((1.0, "m"), (0.3048, "ft"), (1200.0 / 3937.0, "US ft"))
# GeoTIFF keys of the projected and the vertical linear units.
_UNIT_KEYS = (3076, 4099)
_ANGULAR = re.compile(r"degree|radian|grad|arc", re.I)


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


def colourings(stored):
    """What ``pssd render --color`` can colour a cloud by, given its per-point fields.

    Parameters
    ----------
    stored : mapping of str to (n,) array_like
        The cloud's per-point attributes (:attr:`pssd_fast.io.PointCloud.fields`).

    Returns
    -------
    list of str
        ``height``, ``curvature``, ``likelihood`` and ``feature`` always (computed where
        missing); ``displacement``, ``classification``, ``intensity`` and ``rgb`` where the
        cloud holds them.
    """
    return ["height", "curvature", "likelihood", "feature"] + [
        name for name in FROM_CLOUD if _lookup(name, stored) is not None]


def _lookup(name, stored):
    """The arrays of field ``name`` in ``stored`` (names match case-insensitively), or None."""
    by_lower = {key.lower(): key for key in stored}
    keys = [by_lower.get(key) for key in STORED[name]]
    return None if None in keys else [stored[key] for key in keys]


def field_values(name, points, normals=None, stored=None, *, progress=None, **denoise_options):
    """The values of field ``name`` for a cloud, as ``pssd render`` draws them.

    Parameters
    ----------
    name : {"likelihood", "feature", "curvature", "displacement", "classification", \
"intensity", "rgb"}
        The field.
    points : array_like, shape (n, 3)
        The cloud's coordinates.
    normals : array_like, shape (n, 3), optional
        The cloud's stored normals; passed to :func:`pssd_fast.denoise` like ``pssd denoise``
        does (used by its first iteration).
    stored : mapping of str to (n,) array_like, optional
        The cloud's per-point attributes (:attr:`pssd_fast.io.PointCloud.fields`), looked up by
        the names of :data:`STORED` (in any case).
    progress : bool or callable, optional
        Progress of a denoise run, as for :func:`pssd_fast.denoise`.
    **denoise_options
        ``iterations``, ``k``, ``lam``, ``preset``, ``rebuild_graph``, ``n_jobs``, ... of the
        :func:`pssd_fast.denoise` run that computes a missing ``likelihood`` or ``feature``
        (``method`` is always "robust"). Give the options ``pssd denoise`` was given to get
        the values it stores.

    Returns
    -------
    (n,) float64, or (n, 3) float64 for ``rgb``
        ``likelihood`` and ``feature``: as stored, else the result of ``denoise(points,
        normals, **denoise_options)`` rounded to float32 as ``pssd denoise`` stores it, in
        ``[0, 1]``. ``curvature``: :func:`curvature` of the points (never read from the
        cloud). ``displacement``, ``classification`` and ``intensity``: as stored (the
        displacement in the units of the coordinates). ``rgb``: the stored colours in ``[0,
        1]`` (:func:`pssd_fast.pictures.colours.rgb_colours`).

    Raises
    ------
    ValueError
        For an unknown ``name``, a field the cloud does not hold (``displacement``,
        ``classification``, ``intensity``, ``rgb``: the message names what it can be coloured
        by), a stored field of the wrong length, or bad denoise options.
    """
    from ..denoise import denoise

    if name not in FIELDS:
        raise ValueError(f"unknown field {name!r}; choose one of {', '.join(FIELDS)}")
    pts, _ = as_points(points)
    n = pts.shape[0]
    stored = stored or {}
    if name == "curvature":
        return curvature(pts, n_jobs=denoise_options.get("n_jobs"))
    arrays = _lookup(name, stored)
    if arrays is not None:
        arrays = [np.asarray(values) for values in arrays]
        for key, values in zip(STORED[name], arrays, strict=True):
            if values.shape != (n,):
                raise ValueError(f"stored {key} has shape {values.shape}; expected ({n},)")
        return rgb_colours(*arrays) if name == "rgb" else arrays[0].astype(np.float64)
    if name in FROM_CLOUD:
        what = "red, green and blue" if name == "rgb" else name
        hint = ("; render the output of pssd denoise --fields displacement, which stores it"
                if name == "displacement" else "")
        fields = ", ".join(stored) if stored else "none"
        raise ValueError(f"the cloud holds no {what}{hint}; colour it by "
                         f"{', '.join(colourings(stored))} (its per-point fields: {fields})")
    result = denoise(pts, normals, progress=progress, extras=True, **denoise_options)
    # Rounded as pssd denoise stores its added fields (float32), so both pictures agree.
    return getattr(result, STORED[name][0]).astype(np.float32).astype(np.float64)


def units(cloud):
    """Name of the unit of a cloud's coordinates, where its file says it.

    Parameters
    ----------
    cloud : pssd_fast.io.PointCloud

    Returns
    -------
    str or None
        ``"m"``, ``"ft"`` (international foot) or ``"US ft"`` (US survey foot) for a LAS/LAZ
        file whose coordinate system names one linear unit: the GeoTIFF keys of its projected
        and vertical units, or the linear ``UNIT`` of its WKT; None for other files, for LAS
        files without a coordinate system, and where these disagree or name another unit.
    """
    header = getattr(cloud.source, "header", None) if cloud.format == "las" else None
    if header is None:
        return None
    found = set()
    for vlr in list(header.vlrs) + list(getattr(header, "evlrs", None) or []):
        for key in getattr(vlr, "geo_keys", ()):
            if key.id in _UNIT_KEYS and key.tiff_tag_location == 0:
                found.add(_EPSG_UNITS.get(key.value_offset))
        wkt = getattr(vlr, "string", None)
        if isinstance(wkt, str):
            for unit, factor in re.findall(r'(?<![A-Za-z])(?:LENGTH)?UNIT\[\s*"([^"]*)"\s*,'
                                           r'\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)', wkt):
                if not _ANGULAR.search(unit):
                    found.add(next((name for value, name in _WKT_UNITS
                                    if abs(float(factor) - value) < 1e-9), None))
    return found.pop() if len(found) == 1 else None
