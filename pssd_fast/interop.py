"""Point clouds of other libraries in and out: Open3D, trimesh and structured arrays.

:func:`pssd_fast.denoise` (and :func:`pssd_fast.tiled.denoise` and the stage functions) take
these objects directly for their ``points``:

- an Open3D ``open3d.geometry.PointCloud`` or ``open3d.t.geometry.PointCloud`` (its
  ``points``, or ``point.positions`` copied to the CPU);
- a trimesh ``trimesh.PointCloud`` (its ``vertices``);
- a :class:`pssd_fast.io.PointCloud`, as :func:`pssd_fast.io.read` returns it (its
  ``points``);
- a numpy structured array with fields ``X``, ``Y``, ``Z`` (PDAL's arrays) or ``x``, ``y``,
  ``z`` (floating point; laspy's ``points.array`` holds unscaled integers, so pass
  ``las.xyz`` instead). Its ``Classification`` field is the caller's to pass as
  ``classification=``.

A cloud's own normals are not used: ``denoise(cloud)`` is ``denoise`` of its coordinates, bit
for bit (docs/DECISIONS.md, "Clouds of other libraries"). To use them, pass them:
``points, normals = interop.as_arrays(cloud)``, then ``denoise(points, normals)``.

:func:`to_open3d`, :func:`to_trimesh` and :func:`to_structured` give a result back in the
caller's kind of cloud, with the denoised points and normals; with ``like=`` they keep every
other attribute of the input (colours, other fields). Open3D and trimesh are imported only
inside the functions that make their objects; neither is a dependency of pssd_fast.
"""
import importlib
import sys

import numpy as np

__all__ = ["FIELDS", "as_arrays", "coordinates", "to_open3d", "to_structured", "to_trimesh"]

#: Coordinate fields of a structured array, looked for in this order, and the normal fields
#: that go with each (PDAL's ``NormalX``..., PLY's ``nx``...).
FIELDS = ((("X", "Y", "Z"), ("NormalX", "NormalY", "NormalZ")),
          (("x", "y", "z"), ("nx", "ny", "nz")))


def coordinates(points):
    """The coordinates of ``points`` where it is a cloud this module knows (see
    :func:`as_arrays`), else ``points`` unchanged: what the public functions do with their
    ``points`` before checking it."""
    if isinstance(points, np.ndarray) and points.dtype.names is None:
        return points
    if isinstance(points, np.ndarray) or _kind(points) is not None:
        return as_arrays(points)[0]
    return points


def as_arrays(cloud):
    """The coordinates and normals of a point cloud of Open3D or trimesh, or of a structured
    array, as numpy arrays.

    Parameters
    ----------
    cloud : open3d.geometry.PointCloud, open3d.t.geometry.PointCloud, trimesh.PointCloud, \
pssd_fast.io.PointCloud, structured ndarray or (n, 3) ndarray
        A structured array needs floating-point fields ``X``, ``Y``, ``Z`` or ``x``, ``y``,
        ``z``; its normals are the fields ``NormalX``, ``NormalY``, ``NormalZ`` or ``nx``,
        ``ny``, ``nz`` where it has them. A trimesh ``PointCloud`` holds no normals; those in
        its ``metadata["vertex_normals"]`` (where :func:`to_trimesh` puts them) are taken.

    Returns
    -------
    points : (n, 3) ndarray
        A copy, float64 (float32 where the cloud holds float32, as Open3D's tensor clouds
        do by default).
    normals : (n, 3) ndarray or None
        A copy of the cloud's normals, or None where it has none.

    Raises
    ------
    TypeError
        Any other object, naming the conversion to use; a structured array without
        floating-point coordinate fields.

    Examples
    --------
    >>> import numpy as np
    >>> from pssd_fast import interop
    >>> cloud = np.zeros(4, dtype=[("X", "f8"), ("Y", "f8"), ("Z", "f8"), ("Intensity", "u2")])
    >>> points, normals = interop.as_arrays(cloud)
    >>> points.shape, normals
    ((4, 3), None)
    """
    kind = _kind(cloud)
    if kind == "open3d":
        normals = np.array(cloud.normals, dtype=np.float64) if cloud.has_normals() else None
        return np.array(cloud.points, dtype=np.float64), normals
    if kind == "open3d.t":
        attributes = cloud.point
        if "positions" not in attributes:
            return np.empty((0, 3)), None
        normals = attributes.normals.cpu().numpy().copy() if "normals" in attributes else None
        return attributes.positions.cpu().numpy().copy(), normals
    if kind == "pssd_fast":
        return cloud.points.copy(), None if cloud.normals is None else cloud.normals.copy()
    if kind == "trimesh":
        points = np.array(cloud.vertices, dtype=np.float64)
        normals = cloud.metadata.get("vertex_normals")
        if normals is not None and np.shape(normals) == points.shape:
            return points, np.array(normals, dtype=np.float64)
        return points, None
    if isinstance(cloud, np.ndarray):
        if cloud.dtype.names is None:
            return cloud.copy(), None
        if cloud.ndim != 1:
            raise ValueError(f"a structured array of points must be 1-D; got shape "
                             f"{cloud.shape}")
        xyz, normal = _fields(cloud)
        normals = _columns(cloud, normal) if set(normal) <= set(cloud.dtype.names) else None
        return _columns(cloud, xyz), normals
    raise TypeError(f"cannot take the points of {type_name(cloud)}{hint(cloud)}")


def hint(cloud):
    """How to make an (n, 3) array of ``cloud``, an object no public function takes as it is:
    a phrase that starts with ``"; "``, for error messages."""
    # laspy's LasData has points too, but its coordinates in the file's units are xyz.
    for attribute, conversion in (("xyz", "obj.xyz"), ("vertices", "np.asarray(obj.vertices)"),
                                  ("points", "np.asarray(obj.points)")):
        if hasattr(cloud, attribute) and not callable(getattr(cloud, attribute, None)):
            return f"; pass its coordinates as an (n, 3) array: {conversion}"
    return ("; pass an (n, 3) array of coordinates (Open3D and trimesh point clouds and "
            "structured arrays with X, Y, Z fields are converted as they are: "
            "pssd_fast.interop)")


def type_name(obj):
    """``module.Class`` of ``obj``'s type (``Class`` for the builtins), for error messages."""
    kind = type(obj)
    if kind.__module__ == "builtins":
        return kind.__qualname__
    return f"{kind.__module__}.{kind.__qualname__}"


def to_open3d(result, *, tensor=False, like=None):
    """The denoised points and normals as an Open3D point cloud.

    Parameters
    ----------
    result : DenoiseResult or (n, 3) array_like
        What :func:`pssd_fast.denoise` returned (its ``points`` and ``normals``), or
        coordinates alone.
    tensor : bool, default False
        Return an ``open3d.t.geometry.PointCloud`` (positions and normals of the result's
        dtype) instead of the legacy ``open3d.geometry.PointCloud`` (float64).
    like : open3d.geometry.PointCloud or open3d.t.geometry.PointCloud, optional
        The cloud that was denoised: the result is a copy of it (its colours and other
        attributes; with ``remove_outliers``, the rows ``result.kept``) with the new points
        and normals. Of the same API as ``tensor`` asks for.

    Returns
    -------
    open3d.geometry.PointCloud or open3d.t.geometry.PointCloud
        Normals where the result has them; with ``classes``, NaN rows for the points of the
        other classes where none were given.
    """
    o3d = _imported("open3d")
    points, normals = _result_arrays(result)
    cloud = _open3d_copy(like, result, points.shape[0], tensor)
    if tensor:
        device = cloud.device
        cloud.point.positions = o3d.core.Tensor(points).to(device)
        if normals is not None:
            cloud.point.normals = o3d.core.Tensor(normals).to(device)
        return cloud
    cloud.points = o3d.utility.Vector3dVector(points.astype(np.float64))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(normals.astype(np.float64))
    return cloud


def to_trimesh(result, *, like=None):
    """The denoised points as a ``trimesh.PointCloud``, the normals in its metadata.

    Parameters
    ----------
    result : DenoiseResult or (n, 3) array_like
        What :func:`pssd_fast.denoise` returned, or coordinates alone.
    like : trimesh.PointCloud, optional
        The cloud that was denoised: its colours and metadata are kept (with
        ``remove_outliers``, the colours of the rows ``result.kept``).

    Returns
    -------
    trimesh.PointCloud
        ``vertices`` the denoised points (float64); ``metadata["vertex_normals"]`` the normals
        (trimesh's ``PointCloud`` has no attribute for them; the name is the keyword its PLY
        reader uses), where the result has them.
    """
    trimesh = _imported("trimesh")
    points, normals = _result_arrays(result)
    metadata, colors = {}, None
    if like is not None:
        rows = _rows(result, _length(like), points.shape[0])
        metadata = dict(like.metadata)
        metadata.pop("vertex_normals", None)
        given = np.asarray(like.colors)
        if given.shape[:1] == (_length(like),):
            colors = given if rows is None else given[rows]
    if normals is not None:
        metadata["vertex_normals"] = normals.astype(np.float64)
    return trimesh.PointCloud(points.astype(np.float64), colors=colors, metadata=metadata)


def to_structured(result, like, *, add_normals=False):
    """The denoised points written into a copy of a structured array, every other field kept.

    Parameters
    ----------
    result : DenoiseResult or (n, 3) array_like
        What :func:`pssd_fast.denoise` returned, or coordinates alone.
    like : structured ndarray, shape (n,)
        The array that was denoised (PDAL's or laspy-derived records with fields ``X``,
        ``Y``, ``Z`` or ``x``, ``y``, ``z``). With ``remove_outliers``, the copy holds the rows
        ``result.kept``.
    add_normals : bool, default False
        Add the normal fields (``NormalX``, ``NormalY``, ``NormalZ`` beside ``X``...; ``nx``,
        ``ny``, ``nz`` beside ``x``...; float64) where ``like`` has none. Where it has them
        they are always written.

    Returns
    -------
    structured ndarray
        ``like``'s dtype (with ``add_normals``, three more fields); coordinates cast to their
        fields' dtypes. Rows whose result normal is NaN (the other classes of a ``classes``
        run) keep ``like``'s normals.
    """
    if not isinstance(like, np.ndarray) or like.dtype.names is None or like.ndim != 1:
        raise TypeError(f"like must be a 1-D structured array; got {type(like).__name__}")
    points, normals = _result_arrays(result)
    xyz, normal_fields = _fields(like)
    rows = _rows(result, like.shape[0], points.shape[0])
    base = like if rows is None else like[rows]
    has_normals = set(normal_fields) <= set(like.dtype.names)
    if add_normals and not has_normals and normals is not None:
        dtype = [(name, like.dtype.fields[name][0]) for name in like.dtype.names]
        out = np.empty(base.shape[0], dtype + [(name, np.float64) for name in normal_fields])
        for name in like.dtype.names:
            out[name] = base[name]
        for name in normal_fields:
            out[name] = np.nan
        has_normals = True
    else:
        out = base.copy()
    for axis, name in enumerate(xyz):
        out[name] = points[:, axis]
    if has_normals and normals is not None:
        for axis, name in enumerate(normal_fields):
            out[name] = np.where(np.isnan(normals[:, axis]), out[name], normals[:, axis])
    return out


def _kind(cloud):
    """``"open3d"``, ``"open3d.t"``, ``"trimesh"`` or ``"pssd_fast"`` for a point cloud of
    those libraries (this one's: :class:`pssd_fast.io.PointCloud`), else None. A library is
    looked up only where it is imported: an object of its type cannot exist otherwise."""
    ours = sys.modules.get("pssd_fast.io._common")
    if ours is not None and isinstance(cloud, ours.PointCloud):
        return "pssd_fast"
    o3d = sys.modules.get("open3d")
    if o3d is not None:
        if isinstance(cloud, o3d.geometry.PointCloud):
            return "open3d"
        if isinstance(cloud, o3d.t.geometry.PointCloud):
            return "open3d.t"
    trimesh = sys.modules.get("trimesh")
    if trimesh is not None and isinstance(cloud, trimesh.PointCloud):
        return "trimesh"
    return None


def _fields(array):
    """The coordinate fields of a structured array and the normal fields that go with them."""
    names = array.dtype.names
    for xyz, normals in FIELDS:
        if set(xyz) <= set(names):
            kinds = {array.dtype[name].kind for name in xyz}
            if kinds != {"f"}:
                raise TypeError(
                    f"the coordinate fields {', '.join(xyz)} must be floating point; got "
                    f"{', '.join(str(array.dtype[name]) for name in xyz)} (laspy's "
                    f"points.array holds the unscaled LAS integers: pass las.xyz)")
            return xyz, normals
    raise TypeError(f"a structured array of points needs fields X, Y, Z or x, y, z; got "
                    f"{', '.join(names)}")


def _columns(array, names):
    """Fields ``names`` of a structured array as one (n, 3) array (float32 if all are)."""
    dtype = np.result_type(*(array.dtype[name] for name in names))
    return np.column_stack([np.asarray(array[name], dtype) for name in names])


def _result_arrays(result):
    """``(points, normals or None)`` of a result, or of coordinates alone."""
    if hasattr(result, "points") and hasattr(result, "normals"):
        return np.asarray(result.points), (None if result.normals is None
                                           else np.asarray(result.normals))
    points = np.asarray(result)
    if points.ndim != 2 or points.shape[1] != 3 or points.dtype.kind not in "fiu":
        raise TypeError(f"result must be a DenoiseResult or an (n, 3) array of coordinates; "
                        f"got {type(result).__name__} of shape {points.shape}")
    return points, None


def _length(cloud):
    """Number of points of an Open3D (either API) or trimesh cloud."""
    if _kind(cloud) == "open3d":
        return len(cloud.points)
    if _kind(cloud) == "open3d.t":
        return 0 if "positions" not in cloud.point else len(cloud.point.positions)
    if _kind(cloud) == "trimesh":
        return len(cloud.vertices)
    raise TypeError(f"like must be a point cloud of the kind asked for; got "
                    f"{type(cloud).__name__}")


def _rows(result, n_like, n_result):
    """The rows of ``like`` the result holds: None for all of them, or ``result.kept`` where
    ``remove_outliers`` dropped some (``like`` then has the rows kept and those dropped)."""
    if n_like == n_result:
        return None
    kept = getattr(result, "kept", None)
    outliers = getattr(getattr(result, "stats", None), "outliers", None)
    removed = outliers["removed"] if outliers else 0
    if (kept is not None and len(kept) == n_result and n_result and kept[-1] < n_like
            and n_like == n_result + removed):
        return np.asarray(kept)
    raise ValueError(f"like has {n_like} points and the result {n_result}; pass the cloud "
                     f"that was denoised")


def _imported(name):
    """The module ``name`` (open3d or trimesh), or ImportError saying how to install it."""
    try:
        return importlib.import_module(name)
    except ImportError:
        raise ImportError(f"this needs {name}, which is not installed: pip install {name} "
                          f"(or the peers of the comparisons: pip install "
                          f"'pssd_fast[compare]')") from None


def _open3d_copy(like, result, n_result, tensor):
    """A copy of the Open3D cloud ``like`` (of the rows the result holds), of the API
    ``tensor`` asks for; a new empty cloud without ``like``."""
    o3d = _imported("open3d")

    api = o3d.t.geometry if tensor else o3d.geometry
    if like is None:
        return api.PointCloud()
    if not isinstance(like, api.PointCloud):
        name = "open3d.t.geometry" if tensor else "open3d.geometry"
        raise TypeError(f"like must be an {name}.PointCloud with tensor={tensor}; got "
                        f"{type_name(like)}")
    rows = _rows(result, _length(like), n_result)
    if rows is None:
        return like.clone() if tensor else o3d.geometry.PointCloud(like)
    return like.select_by_index(o3d.core.Tensor(rows.astype(np.int64)) if tensor
                                else rows.tolist())
