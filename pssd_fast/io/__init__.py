"""Reading and writing point-cloud files without losing what the scanner put in them.

:func:`read` turns a ``.ply``, ``.xyz``/``.pts``/``.txt``, ``.npy``, ``.npz`` or ``.las``/``.laz``
file into a :class:`PointCloud`: float64 points, normals when the file has them, and every other
per-point attribute (colours, intensity, classification, scalar fields...) in ``fields`` with its
original dtype. :func:`write` writes a cloud back with new points, normals and added per-point
fields (``likelihood``, ``feature_intensity``...), keeping everything else of the input as it was
when the output has the input's format: other PLY properties and elements (faces), comments,
ASCII/binary and byte order; LAS point format, version, scale, offset, every point record, VLRs
and EVLRs; leading comment lines of text files; other arrays of an ``.npz``.

What cannot be carried across formats (the output format follows the output's extension):

* PLY elements other than ``vertex`` (faces, edges...), PLY comments and ``obj_info``, list
  properties of vertices, and LAS headers, VLRs, EVLRs and multi-valued extra bytes exist only
  in their own format; writing to another format drops them.
* ``.npy`` holds points and normals only: fields are dropped with a warning (use ``.npz``).
* Text files store every column as a decimal number: fields come back as float64 (each value
  is written in the shortest form that reads back equal in its own dtype). Only comment lines
  before the data are kept. ``.pts`` output always starts with the point count line; it gets a
  ``# x y z ...`` column line only when the column names differ from what a reader infers by
  default (``x y z``, ``x y z nx ny nz``, or ``col3``...).
* LAS has no normals or free-form attributes: a new LAS file (from a non-LAS cloud) is LAS 1.4,
  point format 6, with per-axis scale the smallest power of ten that fits the extent in int32
  (so coordinates change by at most half of it) and offset the centre of the bounding box;
  normals become float ``nx``/``ny``/``nz`` extra bytes and fields become extra bytes of their
  dtype, except fields named like a standard dimension of format 6 (``intensity``,
  ``classification``, ``gps_time``...), which go there and must fit its type exactly. LAS RGB is
  16-bit, so PLY ``red``/``green``/``blue`` go to extra bytes unchanged rather than rescaled.
* Coordinates written into an existing PLY or NPY/NPZ keep the input's type (float32 stays
  float32); into an existing LAS they are quantised with its scale and offset.

Plain numpy handles NPY, NPZ and text; PLY needs ``plyfile`` and LAS/LAZ ``laspy[lazrs]``
(``pip install 'pssd_fast[io]'``).
"""
import os
import warnings
from pathlib import Path

import numpy as np

from . import las, npy, ply, text
from ._common import (COORDS, NORMALS, PointCloud, PointCloudFileError,
                      PointCloudFileNotFoundError, Source, as_array, as_fields, atomic_write,
                      check_finite, check_names, exists_message)

# Report the public classes where users import them from, not from the private module.
for _cls in (PointCloud, PointCloudFileError, PointCloudFileNotFoundError):
    _cls.__module__ = __name__
del _cls

__all__ = ["PointCloud", "PointCloudFileError", "PointCloudFileNotFoundError", "formats", "read",
           "select", "write"]

# Extension -> PointCloud.format, and the module reading and writing each format.
_FORMATS = {".las": "las", ".laz": "las", ".npy": "npy", ".npz": "npz", ".ply": "ply",
            ".pts": "xyz", ".txt": "xyz", ".xyz": "xyz"}
_MODULES = {"las": las, "npy": npy, "npz": npy, "ply": ply, "xyz": text}


def formats():
    """List the file extensions :func:`read` and :func:`write` understand.

    Returns
    -------
    tuple of str
        Lower-case extensions with their dot, sorted: ``(".las", ".laz", ".npy", ".npz",
        ".ply", ".pts", ".txt", ".xyz")``. Matching is case-insensitive.
    """
    return tuple(_FORMATS)


def read(path):
    """Read a point-cloud file.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply`` (ASCII or binary), ``.xyz``/``.pts``/``.txt`` (whitespace columns), ``.npy``,
        ``.npz`` or ``.las``/``.laz`` file; the extension picks the reader (case-insensitive).

    Returns
    -------
    PointCloud
        Points as float64; normals from PLY ``nx ny nz``, the columns 4-6 of a six-column text
        file or ``.npy`` array, the ``normals`` key of an ``.npz`` or ``nx``/``ny``/``nz`` LAS
        extra bytes; every other per-point attribute in ``fields`` with its dtype.

    Raises
    ------
    PointCloudFileNotFoundError
        If the file does not exist (it is also a ``FileNotFoundError``).
    PointCloudFileError
        On an unknown extension, a directory, malformed or truncated content, a header that
        claims more points than the file can hold (checked before anything is allocated),
        NaN or Inf coordinates, or no points at all. The message is one line naming the file.
    ImportError
        If ``plyfile`` (PLY) or ``laspy[lazrs]`` (LAS/LAZ) is not installed.

    Notes
    -----
    Text files: ``#`` starts a comment; a first line holding a single integer is a point count
    (as in PTS files) and must match the number of rows. Three columns are points, six are
    points and normals, other counts are points followed by fields ``col3``, ``col4``... unless
    the last comment line before the data names every column (``# x y z nx ny nz likelihood``,
    as :func:`write` puts it), in which case those names are used.
    """
    path = _checked_path(path)
    if not path.exists():
        raise PointCloudFileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise PointCloudFileError(f"{path}: is a directory, not a point-cloud file")
    kind = _FORMATS[path.suffix.lower()]
    points, normals, fields, source = _MODULES[kind].read(path)
    if len(points) == 0:
        raise PointCloudFileError(f"{path}: holds no points")
    check_finite(path, points)
    return PointCloud(points, normals, fields, kind, source)


def write(path, cloud, *, points=None, normals=None, fields=None, overwrite=False):
    """Write a point cloud, atomically, in the format of the output's extension.

    Parameters
    ----------
    path : str or os.PathLike
        The output file; its extension (see :func:`formats`) picks the format.
    cloud : PointCloud
        The cloud to write, usually from :func:`read`.
    points : (n, 3) array_like, optional
        Coordinates replacing ``cloud.points`` (same number of points).
    normals : (n, 3) array_like, optional
        Normals replacing ``cloud.normals``.
    fields : dict of str to (n,) array_like, optional
        Per-point values added as new properties (PLY), columns (text), arrays (NPZ) or extra
        bytes (LAS), each with its own dtype (e.g. float64). A name the cloud already has
        replaces that attribute's values, which must then fit its stored type exactly unless
        it is a float type. Names may not contain whitespace nor be ``x y z nx ny nz``.
    overwrite : bool, default False
        Replace an existing file, the input file of ``cloud`` included.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    PointCloudFileError
        On an unknown extension, a directory as ``path``, NaN or Inf coordinates, arrays of
        the wrong shape or values that do not fit the output (a subclass of ``ValueError``).
    ImportError
        If ``plyfile`` (PLY) or ``laspy[lazrs]`` (LAS/LAZ) is not installed.

    Notes
    -----
    When the output has the format of ``cloud``'s source file, everything of that file is
    written back unchanged except the coordinates, normals and fields given (see the module
    documentation for what other formats cannot hold). The data goes to a temporary file in
    the output's folder that is renamed onto ``path`` only once complete; on any error it is
    removed and ``path`` is left as it was. The input file is never opened for writing.
    """
    path = _checked_path(path)
    if not path.parent.is_dir():
        raise PointCloudFileNotFoundError(f"{path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise PointCloudFileError(f"{path}: is a directory, not a file name")
    if not overwrite and path.exists():
        raise FileExistsError(exists_message(path, cloud))
    n = len(cloud)
    pts = cloud.points if points is None else as_array(path, points, "points", (n, 3))
    check_finite(path, pts)
    nrm = cloud.normals if normals is None else as_array(path, normals, "normals", (n, 3))
    try:
        new = as_fields(fields or {}, n)
    except ValueError as exc:
        raise PointCloudFileError(f"{path}: {exc}") from None
    check_names(path, new, "field names")
    reserved = sorted(set(new) & set(COORDS + NORMALS))
    if reserved:
        raise PointCloudFileError(f"{path}: field names {reserved} are reserved for the "
                                  f"coordinates and normals (pass points= or normals=)")
    merged = {**cloud.fields, **new}
    ext = path.suffix.lower()
    kind = _FORMATS[ext]
    if kind in ("ply", "xyz"):
        check_names(path, merged, f"a {ext} file")
    source = cloud.source if cloud.format == kind else None
    if kind == "npy" and merged:
        warnings.warn(f"{path}: .npy holds only points and normals; fields {list(merged)} are "
                      f"not written (use .npz, .ply or .las to keep them)", stacklevel=2)
    payload = _MODULES[kind].payload(path, pts, nrm, merged, source)
    atomic_write(path, payload, overwrite, cloud)
    return path


def select(cloud, rows):
    """The cloud's ``rows`` only, with everything :func:`write` keeps of its source file.

    Parameters
    ----------
    cloud : PointCloud
    rows : (m,) int array_like or (n,) bool array_like
        Row indices or a mask, as for numpy indexing.

    Returns
    -------
    PointCloud
        Points, normals, fields and the source's per-point records (LAS point records, PLY
        vertex rows) of those rows; header, VLRs, comments and the other arrays of an
        ``.npz`` are kept as they are.

    Raises
    ------
    PointCloudFileError
        If the cloud comes from a PLY file with elements other than vertices (faces index the
        vertices, and would silently point at other ones).
    """
    rows = np.asarray(rows)
    if rows.dtype.kind not in "biu" or rows.ndim != 1:
        raise TypeError(f"rows must be a 1-d integer or boolean array; got {rows.dtype} with "
                        f"shape {rows.shape}")
    source = cloud.source.take(rows) if isinstance(cloud.source, Source) else cloud.source
    return PointCloud(cloud.points[rows], None if cloud.normals is None else cloud.normals[rows],
                      {name: values[rows] for name, values in cloud.fields.items()},
                      cloud.format, source)


def _checked_path(path):
    """``path`` as a Path with a supported extension."""
    path = Path(os.fspath(path))
    ext = path.suffix.lower()
    if ext not in _FORMATS:
        what = f"unknown extension {path.suffix!r}" if ext else "no extension"
        raise PointCloudFileError(f"{path}: {what}; supported: {', '.join(formats())}")
    return path
