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
import copy
import importlib
import io
import math
import os
import re
import secrets
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["PointCloud", "PointCloudFileError", "PointCloudFileNotFoundError", "formats", "read",
           "write"]

# Extension -> PointCloud.format.
_FORMATS = {".las": "las", ".laz": "las", ".npy": "npy", ".npz": "npz", ".ply": "ply",
            ".pts": "xyz", ".txt": "xyz", ".xyz": "xyz"}
_COORDS = ("x", "y", "z")
_NORMALS = ("nx", "ny", "nz")
_INSTALL = "pip install 'pssd_fast[io]'"

# A PLY header is a few hundred bytes; a file without "end_header" in its first MiB is not PLY.
_PLY_HEADER_LIMIT = 2**20
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4,
              "float32": 4, "double": 8, "float64": 8}
_PLY_END = re.compile(rb"(?:^|[\r\n])end_header[ \t]*(?:\r\n|\r|\n)")
# Types PLY can store, and where 64-bit or bool values go instead (if they fit exactly).
_PLY_KINDS = {"i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"}
_PLY_NARROW = {"b1": "u1", "i8": "i4", "u8": "u4"}
# LAS point records are read in pieces so that a header claiming more points than the file
# holds costs at most one piece of memory before the shortfall is noticed.
_LAS_CHUNK = 2**20
_TEXT_CHUNK = 2**16  # rows formatted at once when writing text


class PointCloudFileError(ValueError):
    """A point-cloud file that cannot be read or written; the message names the file."""


class PointCloudFileNotFoundError(PointCloudFileError, FileNotFoundError):
    """The file to read, or the folder to write into, does not exist."""


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A point cloud as read from a file, with whatever is needed to write it back.

    Parameters
    ----------
    points : (n, 3) array_like
        Coordinates; stored as float64.
    normals : (n, 3) array_like or None
        Per-point normals (stored as float64), or None.
    fields : dict of str to (n,) numpy.ndarray
        Every other per-point attribute of the file, with its original dtype.
    format : str
        ``"ply"``, ``"xyz"`` (also ``.pts`` and ``.txt``), ``"npy"``, ``"npz"`` or ``"las"``
        (also ``.laz``): the format read. Clouds built in memory default to ``"npy"``.
    source : object
        Opaque: what :func:`write` needs to reproduce the rest of the input file (the parsed
        PLY, the LAS header and point records, the comment lines of a text file...). None for
        clouds built in memory.

    Notes
    -----
    ``len(cloud)`` is the number of points. Use ``dataclasses.replace`` to derive a cloud with
    other points, normals or fields; it keeps ``source``.
    """

    points: np.ndarray
    normals: np.ndarray = None
    fields: dict = field(default_factory=dict)
    format: str = "npy"
    source: object = field(default=None, repr=False)

    def __post_init__(self):
        points = np.asarray(self.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3); got {points.shape}")
        object.__setattr__(self, "points", points)
        if self.normals is not None:
            normals = np.asarray(self.normals, dtype=np.float64)
            if normals.shape != points.shape:
                raise ValueError(f"normals must have shape {points.shape}; got {normals.shape}")
            object.__setattr__(self, "normals", normals)
        object.__setattr__(self, "fields", _as_fields(self.fields, len(points)))

    def __len__(self):
        return len(self.points)

    def __repr__(self):
        return (f"PointCloud(n={len(self)}, normals={self.normals is not None}, "
                f"fields={list(self.fields)}, format={self.format!r})")


@dataclass(frozen=True)
class _Source:
    """Where a cloud was read from; subclasses add what its format needs to be written back."""

    path: str  # absolute, so that writing onto the input is recognised from any folder


@dataclass(frozen=True)
class _PlySource(_Source):
    ply: object  # plyfile.PlyData with all elements in memory


@dataclass(frozen=True)
class _LasSource(_Source):
    header: object  # laspy.LasHeader, VLRs and EVLRs included; deep-copied before each write
    records: np.ndarray  # the raw point records (structured array of the point format)


@dataclass(frozen=True)
class _TextSource(_Source):
    comments: tuple  # leading comment lines, verbatim, without the column-name line


@dataclass(frozen=True)
class _ArraySource(_Source):
    dtype: np.dtype  # of the points array (npy: of the whole array), kept on write if float
    normals_dtype: np.dtype = None  # npz: of the normals array, likewise
    compressed: bool = False  # npz: zip-deflated members
    extras: dict = field(default_factory=dict)  # npz: arrays that are not per-point fields


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
    ext = path.suffix.lower()
    reader = {"ply": _read_ply, "xyz": _read_text, "npy": _read_npy, "npz": _read_npz,
              "las": _read_las}[_FORMATS[ext]]
    points, normals, fields, source = reader(path)
    if len(points) == 0:
        raise PointCloudFileError(f"{path}: holds no points")
    _check_finite(path, points)
    return PointCloud(points, normals, fields, _FORMATS[ext], source)


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
        raise FileExistsError(_exists_message(path, cloud))
    n = len(cloud)
    pts = cloud.points if points is None else _as_array(path, points, "points", (n, 3))
    _check_finite(path, pts)
    nrm = cloud.normals if normals is None else _as_array(path, normals, "normals", (n, 3))
    try:
        new = _as_fields(fields or {}, n)
    except ValueError as exc:
        raise PointCloudFileError(f"{path}: {exc}") from None
    _check_names(path, new, "field names")
    reserved = sorted(set(new) & set(_COORDS + _NORMALS))
    if reserved:
        raise PointCloudFileError(f"{path}: field names {reserved} are reserved for the "
                                  f"coordinates and normals (pass points= or normals=)")
    merged = {**cloud.fields, **new}
    ext = path.suffix.lower()
    kind = _FORMATS[ext]
    if kind in ("ply", "xyz"):
        _check_names(path, merged, f"a {ext} file")
    source = cloud.source if cloud.format == kind else None
    if kind == "npy" and merged:
        warnings.warn(f"{path}: .npy holds only points and normals; fields {list(merged)} are "
                      f"not written (use .npz, .ply or .las to keep them)", stacklevel=2)
    if kind == "ply":
        payload = _ply_payload(path, pts, nrm, merged, source)
    elif kind == "las":
        payload = _las_payload(path, pts, nrm, merged, source, ext == ".laz")
    elif kind == "xyz":
        payload = _text_payload(pts, nrm, merged, source, ext == ".pts")
    else:
        payload = _array_payload(path, pts, nrm, merged, source, kind == "npz")
    _atomic_write(path, payload, overwrite, cloud)
    return path


# ---------------------------------------------------------------------------------------------
# Shared checks


def _checked_path(path):
    """``path`` as a Path with a supported extension."""
    path = Path(os.fspath(path))
    ext = path.suffix.lower()
    if ext not in _FORMATS:
        what = f"unknown extension {path.suffix!r}" if ext else "no extension"
        raise PointCloudFileError(f"{path}: {what}; supported: {', '.join(formats())}")
    return path


def _check_finite(path, points):
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise PointCloudFileError(
            f"{path}: {int(bad.sum()):,} of {len(points):,} points have NaN or Inf coordinates "
            f"(the first is point {int(np.flatnonzero(bad)[0])})")


def _as_array(path, values, name, shape):
    arr = np.asarray(values)
    if arr.shape != shape or arr.dtype.kind not in "fiu":
        raise PointCloudFileError(f"{path}: {name} must be a real array of shape {shape}; got "
                                  f"shape {arr.shape}, dtype {arr.dtype}")
    return arr.astype(np.float64)


def _as_fields(fields, n):
    """A new dict of (n,) numeric arrays keyed by non-empty strings."""
    out = {}
    for name, values in fields.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"field name {name!r} must be a non-empty string")
        arr = np.asarray(values)
        if arr.shape != (n,) or arr.dtype.kind not in "biuf":
            raise ValueError(f"field {name!r} must be a numeric array of shape ({n},); got "
                             f"shape {arr.shape}, dtype {arr.dtype}")
        out[name] = arr
    return out


def _check_names(path, names, what):
    """Refuse names that would break a PLY header line or a text column line."""
    bad = [name for name in names if any(c.isspace() for c in name)]
    if bad:
        raise PointCloudFileError(f"{path}: {what} cannot hold names with spaces: {bad}")


def _fit(name, values, dtype, where):
    """``values`` as ``dtype``; integer and bool targets must hold them exactly."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return values.astype(dtype)
    with np.errstate(invalid="ignore", over="ignore"):
        cast = values.astype(dtype)
    if not np.array_equal(cast, values):
        raise ValueError(f"field {name!r} does not fit the {dtype} type of {where}")
    return cast


def _exists_message(path, cloud):
    src = cloud.source
    if isinstance(src, _Source) and os.path.exists(src.path) and os.path.samefile(path, src.path):
        return (f"{path}: is the file this cloud was read from; refusing to overwrite the input "
                f"(pass overwrite=True, --force on the command line, to replace it)")
    return (f"{path}: already exists; pass overwrite=True (--force on the command line) to "
            f"replace it")


def _atomic_write(path, payload, overwrite, cloud):
    """Run ``payload(file)`` on a temporary file next to ``path``, then rename it onto ``path``.

    The temporary file is in the same folder so that ``os.replace`` is an atomic rename on the
    same file system; it is created with ``open(..., "xb")`` so that it gets the usual
    permissions (umask) rather than mkstemp's private ones.
    """
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    try:
        with open(tmp, "xb") as fh:
            payload(fh)
            fh.flush()
            os.fsync(fh.fileno())
        # Checked again: another process may have created the file while this one wrote.
        if not overwrite and path.exists():
            raise FileExistsError(_exists_message(path, cloud))
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _need(module, package, what):
    """Import an optional dependency, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"{what} needs {package}: {_INSTALL}") from exc


# ---------------------------------------------------------------------------------------------
# PLY


@dataclass(frozen=True)
class _PlyLayout:
    ascii: bool
    header_lines: int
    counts: dict  # element name -> row count, in file order


def _ply_layout(path, fh, size):
    """Parse the header enough to check its element counts against the file size.

    plyfile allocates every element from its header count before reading a row, so a header
    claiming a billion vertices must be refused here, from the bytes a row needs at least:
    its fixed size in binary files, two characters per value (digit and separator) in ASCII.
    """
    head = fh.read(_PLY_HEADER_LIMIT)
    if not head.startswith(b"ply"):
        raise PointCloudFileError(f"{path}: not a PLY file (it does not start with 'ply')")
    end = _PLY_END.search(head)
    if end is None:
        raise PointCloudFileError(f"{path}: PLY header has no 'end_header' line (truncated or "
                                  f"not a PLY file)")
    lines = head[:end.end()].decode("ascii", "replace").splitlines()
    fmt, elements = None, []  # elements: [name, count, bytes per row at least]
    for lineno, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0] == "format" and len(tokens) > 1:
            fmt = tokens[1]
        elif tokens[0] == "element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise PointCloudFileError(f"{path}: bad PLY header line {lineno}: {line!r}")
            elements.append([tokens[1], int(tokens[2]), 0])
        elif tokens[0] == "property" and elements:
            # A list costs at least its length field (it may be empty): its first type.
            type_ = [*tokens, "", ""][2 if tokens[1:2] == ["list"] else 1]
            if type_ not in _PLY_SIZES:
                raise PointCloudFileError(f"{path}: unknown PLY type on header line {lineno}: "
                                          f"{line!r}")
            elements[-1][2] += 2 if fmt == "ascii" else _PLY_SIZES[type_]
    have = size - end.end()
    need = 0
    for name, count, row in elements:
        need += count * row
        # An ASCII file may lack the final newline.
        if need > have + (fmt == "ascii"):
            raise PointCloudFileError(
                f"{path}: header claims {count:,} '{name}' elements, which need at least "
                f"{need:,} bytes, but only {have:,} bytes follow the header (truncated file or "
                f"wrong header)")
    return _PlyLayout(fmt == "ascii", len(lines), {name: count for name, count, _ in elements})


def _ply_parse_error(path, exc, layout, plyfile):
    """One-line message for a plyfile parse error, with the file line for ASCII data."""
    if isinstance(exc, plyfile.PlyHeaderParseError):
        return PointCloudFileError(f"{path}: bad PLY header (line {exc.line}): {exc.message}")
    name = exc.element.name if exc.element is not None else "?"
    if exc.message == "early end-of-file":
        return PointCloudFileError(f"{path}: truncated: element '{name}' ends after {exc.row:,} "
                                   f"of {layout.counts.get(name, 0):,} rows")
    where = f"row {exc.row} of element '{name}'"
    if layout.ascii and exc.row is not None:
        before = 0
        for other, count in layout.counts.items():
            if other == name:
                break
            before += count
        where = f"line {layout.header_lines + before + exc.row + 1} ('{name}' row {exc.row})"
    prop = f", property '{exc.prop.name}'" if exc.prop is not None else ""
    return PointCloudFileError(f"{path}: {exc.message} on {where}{prop}")


def _read_ply(path):
    plyfile = _need("plyfile", "plyfile", "Reading .ply files")
    with open(path, "rb") as fh:
        layout = _ply_layout(path, fh, os.fstat(fh.fileno()).st_size)
        fh.seek(0)
        try:
            ply = plyfile.PlyData.read(fh)
        except plyfile.PlyParseError as exc:
            raise _ply_parse_error(path, exc, layout, plyfile) from None
        except UnicodeDecodeError:
            raise PointCloudFileError(f"{path}: non-ASCII bytes in the PLY header or in its "
                                      f"ASCII data") from None
    for element in ply.elements:
        # plyfile memory-maps binary elements copy-on-write; untouched pages of such a map
        # follow later changes of the file, so the cloud takes its own copy.
        element.data = np.array(element.data)
    if "vertex" not in ply:
        raise PointCloudFileError(f"{path}: has no 'vertex' element")
    vertex = ply["vertex"]
    scalar = [p.name for p in vertex.properties if not isinstance(p, plyfile.PlyListProperty)]
    missing = [c for c in _COORDS if c not in scalar]
    if missing:
        raise PointCloudFileError(f"{path}: vertex element has no {', '.join(missing)} property")
    data = vertex.data
    points = np.column_stack([data[c] for c in _COORDS]).astype(np.float64)
    normals = None
    if all(c in scalar for c in _NORMALS):
        normals = np.column_stack([data[c] for c in _NORMALS]).astype(np.float64)
    fields = {name: data[name].astype(data.dtype[name].newbyteorder("="))
              for name in scalar if name not in _COORDS + _NORMALS}
    return points, normals, fields, _PlySource(os.path.abspath(path), ply)


def _ply_values(name, values):
    """``values`` in a type PLY can store (64-bit and bool values narrowed if they fit)."""
    code = values.dtype.str[1:]
    if code in _PLY_KINDS:
        return values
    if code in _PLY_NARROW:
        return _fit(name, values, _PLY_NARROW[code], "a PLY property")
    raise ValueError(f"field {name!r} has dtype {values.dtype}, which PLY cannot store")


def _ply_payload(path, points, normals, fields, source):
    plyfile = _need("plyfile", "plyfile", "Writing .ply files")
    columns, lists = {}, {}  # name -> (n,) values; name -> list property of the source
    comments = []
    if source is not None:
        vertex = source.ply["vertex"]
        comments = vertex.comments
        for prop in vertex.properties:
            columns[prop.name] = vertex.data[prop.name]
            if isinstance(prop, plyfile.PlyListProperty):
                lists[prop.name] = prop
    coord_type = columns["x"].dtype if "x" in columns else np.dtype(np.float64)
    try:
        for group, values in ((_COORDS, points), (_NORMALS, normals)):
            if values is not None:
                for i, name in enumerate(group):
                    stored = columns[name].dtype if name in columns else coord_type
                    columns[name] = _fit(name, values[:, i], stored, "the PLY coordinates")
        for name, values in fields.items():
            if name in lists:
                raise ValueError(f"field {name!r} is a list property of the input PLY")
            if name in columns:
                if not np.array_equal(columns[name], values):
                    columns[name] = _fit(name, values, columns[name].dtype, "its PLY property")
            else:
                columns[name] = _ply_values(name, values)
    except ValueError as exc:
        raise PointCloudFileError(f"{path}: {exc}") from None
    data = np.empty(len(points), dtype=[(name, col.dtype.newbyteorder("="))
                                        for name, col in columns.items()])
    for name, col in columns.items():
        data[name] = col
    element = plyfile.PlyElement.describe(
        data, "vertex", len_types={k: p.len_dtype for k, p in lists.items()},
        val_types={k: p.val_dtype for k, p in lists.items()},
        comments=comments)
    if source is None:
        return plyfile.PlyData([element], text=False, byte_order="<").write
    base = source.ply
    return plyfile.PlyData([element if e.name == "vertex" else e for e in base.elements],
                           text=base.text, byte_order=base.byte_order, comments=base.comments,
                           obj_info=base.obj_info).write


# ---------------------------------------------------------------------------------------------
# Text columns (.xyz, .pts, .txt)


def _default_names(ncols):
    """Column names a reader infers for a text file without a column-name comment."""
    if ncols == 6:
        return [*_COORDS, *_NORMALS]
    return [*_COORDS, *(f"col{i}" for i in range(3, ncols))]


def _text_parse_error(path, text, start, first_line, ncols, exc):
    """Find the first line numpy refused (slow, only after a failure) and describe it."""
    for offset, line in enumerate(text[start:].split("\n")):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if len(tokens) != ncols:
            return PointCloudFileError(f"{path}: line {first_line + offset} has {len(tokens)} "
                                       f"columns; the first data line has {ncols}")
        for token in tokens:
            try:
                float(token)
            except ValueError:
                return PointCloudFileError(f"{path}: bad number {token!r} on line "
                                           f"{first_line + offset}")
    return PointCloudFileError(f"{path}: {' '.join(str(exc).split())}")


def _read_text(path):
    # Undecodable bytes are kept as surrogates so that comments are written back verbatim.
    with open(path, encoding="utf-8", errors="surrogateescape") as fh:
        text = fh.read()
    comments, count, pos, lineno = [], None, 0, 1
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end]
        tokens = line.split("#", 1)[0].split()
        if tokens:
            if count is not None or len(tokens) != 1 or not tokens[0].isdigit():
                break
            count = int(tokens[0])  # a PTS point-count line, before any data
        elif line.strip():
            comments.append(line)
        pos, lineno = end + 1, lineno + 1
    if pos >= len(text):
        if count:
            raise PointCloudFileError(f"{path}: first line says {count:,} points but the file "
                                      f"holds none")
        return np.empty((0, 3)), None, {}, None
    ncols = len(tokens)
    if ncols < 3:
        raise PointCloudFileError(f"{path}: line {lineno} has {ncols} columns; x y z need 3")
    # Each row takes at least two characters per value: refuse absurd counts before parsing.
    if count is not None and count * 2 * ncols > len(text) - pos + 1:
        raise PointCloudFileError(f"{path}: first line says {count:,} points, more than the "
                                  f"{len(text) - pos:,} characters after it can hold")
    try:
        data = np.loadtxt(io.StringIO(text[pos:]), dtype=np.float64, comments="#", ndmin=2)
    except ValueError as exc:
        raise _text_parse_error(path, text, pos, lineno, ncols, exc) from None
    if count is not None and count != len(data):
        raise PointCloudFileError(f"{path}: first line says {count:,} points but the file holds "
                                  f"{len(data):,}")
    names = _default_names(ncols)
    if comments:
        named = comments[-1].split("#", 1)[-1].split()
        if len(named) == ncols and named[:3] == list(_COORDS) and len(set(named)) == ncols:
            names = named
            comments.pop()
    column = {name: data[:, i] for i, name in enumerate(names)}
    normals = None
    if all(c in column for c in _NORMALS):
        normals = np.column_stack([column[c] for c in _NORMALS])
    fields = {name: np.ascontiguousarray(col) for name, col in column.items()
              if name not in _COORDS + _NORMALS}
    source = _TextSource(os.path.abspath(path), tuple(comments))
    return data[:, :3].copy(), normals, fields, source


def _text_column(values):
    """Decimal strings of ``values``: numpy prints the shortest string that reads back equal."""
    if values.dtype.kind == "b":
        values = values.astype(np.uint8)
    return values.astype(str).tolist()


def _text_payload(points, normals, fields, source, pts):
    names, columns = list(_COORDS), [points[:, 0], points[:, 1], points[:, 2]]
    if normals is not None:
        names += _NORMALS
        columns += [normals[:, 0], normals[:, 1], normals[:, 2]]
    names += fields
    columns += fields.values()
    head = list(source.comments) if source is not None else []
    # PTS readers expect the count first; they get a column line only when they need one.
    if not pts or names != _default_names(len(names)):
        head.append("# " + " ".join(names))
    if pts:
        head.append(str(len(points)))

    def payload(fh):
        fh.write("".join(line + "\n" for line in head).encode("utf-8", "surrogateescape"))
        for start in range(0, len(points), _TEXT_CHUNK):
            rows = zip(*(_text_column(c[start:start + _TEXT_CHUNK]) for c in columns),
                       strict=True)
            fh.write("".join(" ".join(row) + "\n" for row in rows).encode("ascii"))
    return payload


# ---------------------------------------------------------------------------------------------
# NPY / NPZ


def _npy_header(path, fh, size, what):
    """Shape and dtype from an .npy header, checked against the ``size`` bytes available."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = fmt.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = fmt.read_array_header_2_0(fh)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except ValueError as exc:
        raise PointCloudFileError(f"{path}: {what} is not a valid .npy array ({exc})") from None
    if dtype.hasobject:
        raise PointCloudFileError(f"{path}: {what} holds Python objects, which are not loaded")
    need = math.prod(shape) * dtype.itemsize
    have = size - fh.tell()
    if need > have:
        raise PointCloudFileError(f"{path}: {what} claims shape {shape} ({need:,} bytes) but "
                                  f"only {have:,} bytes follow its header (truncated)")
    return shape, dtype


def _read_npy(path):
    with open(path, "rb") as fh:
        shape, dtype = _npy_header(path, fh, os.fstat(fh.fileno()).st_size, "the array")
        if len(shape) != 2 or shape[1] not in (3, 6) or dtype.kind not in "fiu":
            raise PointCloudFileError(f"{path}: expected an (n, 3) or (n, 6) numeric array; "
                                      f"got shape {shape}, dtype {dtype}")
        fh.seek(0)
        arr = np.lib.format.read_array(fh, allow_pickle=False)
    normals = arr[:, 3:].astype(np.float64) if shape[1] == 6 else None
    source = _ArraySource(os.path.abspath(path), arr.dtype)
    return arr[:, :3].astype(np.float64), normals, {}, source


def _read_npz(path):
    arrays = {}
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            for info in infos:
                key = info.filename.removesuffix(".npy")
                if key == info.filename:
                    raise PointCloudFileError(f"{path}: member {info.filename!r} is not an "
                                              f".npy array")
                with zf.open(info) as member:
                    _npy_header(path, member, info.file_size, f"array {key!r}")
                with zf.open(info) as member:
                    arrays[key] = np.lib.format.read_array(member, allow_pickle=False)
    except PointCloudFileError:
        raise
    except (zipfile.BadZipFile, EOFError, ValueError) as exc:
        raise PointCloudFileError(f"{path}: not a readable .npz (zip) archive, truncated or "
                                  f"corrupt ({exc})") from None
    points = arrays.pop("points", None)
    if points is None or points.ndim != 2 or points.shape[1] != 3 or points.dtype.kind not in "fiu":
        got = "no 'points' array" if points is None else f"'points' of shape {points.shape}"
        raise PointCloudFileError(f"{path}: needs a numeric (n, 3) 'points' array; {got}")
    n = len(points)
    normals = arrays.pop("normals", None)
    if normals is not None and normals.shape != (n, 3):
        raise PointCloudFileError(f"{path}: 'normals' has shape {normals.shape}; expected "
                                  f"{(n, 3)}")
    fields = {k: a for k, a in arrays.items() if a.shape == (n,) and a.dtype.kind in "biuf"}
    extras = {k: a for k, a in arrays.items() if k not in fields}
    compressed = any(i.compress_type != zipfile.ZIP_STORED for i in infos)
    source = _ArraySource(os.path.abspath(path), points.dtype,
                          None if normals is None else normals.dtype, compressed, extras)
    normals = None if normals is None else normals.astype(np.float64)
    return points.astype(np.float64), normals, fields, source


def _float_dtype(dtype):
    """The input's float type, kept; integer arrays cannot hold moved points or normals."""
    return dtype if dtype is not None and dtype.kind == "f" else np.dtype(np.float64)


def _array_payload(path, points, normals, fields, source, npz):
    dtype = _float_dtype(source.dtype if source is not None else None)
    if not npz:
        arr = points if normals is None else np.hstack([points, normals])
        return lambda fh: np.save(fh, arr.astype(dtype))
    arrays = dict(source.extras) if source is not None else {}
    clash = {"points", "normals"} & set(fields)
    if clash:
        raise PointCloudFileError(f"{path}: field names {sorted(clash)} are the .npz keys of "
                                  f"the points and normals")
    arrays.update(fields, points=points.astype(dtype))
    if normals is not None:
        arrays["normals"] = normals.astype(
            _float_dtype(source.normals_dtype if source is not None else None))
    save = np.savez_compressed if source is not None and source.compressed else np.savez
    return lambda fh: save(fh, **arrays)


# ---------------------------------------------------------------------------------------------
# LAS / LAZ


def _need_laspy(path, what):
    laspy = _need("laspy", "laspy[lazrs]", f"{what} .las/.laz files")
    if path.suffix.lower() == ".laz" and not laspy.LazBackend.LazrsParallel.is_available():
        raise ImportError(f"{what} .laz files needs laspy[lazrs] (the lazrs backend): "
                          f"{_INSTALL}")
    return laspy


def _read_las(path):
    laspy = _need_laspy(path, "Reading")
    # laspy's own errors, lazrs' (RuntimeError) and struct/EOF errors of a short header.
    failures = (laspy.LaspyException, RuntimeError, ValueError, EOFError)

    def corrupt(exc):
        return PointCloudFileError(f"{path}: cannot read LAS/LAZ data (truncated or corrupt "
                                   f"file): {' '.join(str(exc).split())}")

    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            reader = laspy.LasReader(fh, closefd=False)
        except failures as exc:
            raise corrupt(exc) from None
        header = reader.header
        n = header.point_count
        need = header.offset_to_point_data + n * header.point_format.size
        if not header.are_points_compressed and need > size:
            raise PointCloudFileError(
                f"{path}: header claims {n:,} points ({need:,} bytes with the header) but the "
                f"file has {size:,} bytes (truncated file or wrong header)")
        chunks, got = [], 0
        try:
            while got < n:
                chunk = reader.read_points(min(_LAS_CHUNK, n - got)).array
                if len(chunk) == 0:
                    break
                chunks.append(chunk)
                got += len(chunk)
        except failures as exc:
            raise corrupt(exc) from None
    if got < n:
        raise PointCloudFileError(f"{path}: header claims {n:,} points but only {got:,} could "
                                  f"be read (truncated)")
    records = np.concatenate(chunks) if chunks else np.zeros(0, header.point_format.dtype())
    rec = laspy.ScaleAwarePointRecord(records, header.point_format, header.scales,
                                      header.offsets)
    points = np.column_stack([records[c] * s + o for c, s, o in
                              zip("XYZ", header.scales, header.offsets, strict=True)])
    # Copies: fields must not be views into the records kept for writing back.
    values = {name: np.array(rec[name]) for name in header.point_format.dimension_names
              if name not in ("X", "Y", "Z")}
    # Multi-valued extra bytes stay in the records only: fields are one value per point.
    values = {k: v for k, v in values.items() if v.ndim == 1}
    normals = None
    if all(c in values for c in _NORMALS):
        normals = np.column_stack([values.pop(c) for c in _NORMALS]).astype(np.float64)
    return points, normals, values, _LasSource(os.path.abspath(path), header, records)


def _quantise(path, coords, scales, offsets):
    """Integer LAS coordinates; unmodified coordinates give back their integers exactly.

    ``x = X * scale + offset`` is off by at most about 1e-16 |x| in float64, so
    ``(x - offset) / scale`` is within 1e-16 |x| / scale of the integer ``X``: rounding
    recovers it whenever the scale exceeds a few 1e-16 |x| (at a UTM northing of 4e6 m, any
    scale above ~1e-9 m), far finer than any real LAS scale.
    """
    q = np.rint((coords - offsets) / scales)
    info = np.iinfo(np.int32)
    if q.size and (q.min() < info.min or q.max() > info.max):
        raise PointCloudFileError(f"{path}: coordinates outside what a LAS file with scale "
                                  f"{scales.tolist()} and offset {offsets.tolist()} can hold")
    return q.astype(np.int32)


def _new_las(laspy, points):
    """LAS 1.4, point format 6, with a per-axis scale that keeps the extent inside int32."""
    header = laspy.LasHeader(version="1.4", point_format=6)
    lo, hi = points.min(axis=0), points.max(axis=0)
    header.offsets = (lo + hi) / 2
    # 2**30 leaves a factor of two for rounding up to a power of ten; 1e-3 floors the
    # half-extent of flat or single-point clouds (scale 1e-12).
    header.scales = 10.0 ** np.ceil(np.log10(np.maximum((hi - lo) / 2, 1e-3) / 2**30))
    return laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(len(points),
                                                                          header=header))


def _las_payload(path, points, normals, fields, source, compress):
    laspy = _need_laspy(path, "Writing")
    if source is None:
        las = _new_las(laspy, points)
    else:
        header = copy.deepcopy(source.header)  # laspy's writer edits the header it writes
        las = laspy.LasData(header, points=laspy.PackedPointRecord(source.records.copy(),
                                                                   header.point_format))
    header = las.header
    quantised = _quantise(path, points, header.scales, header.offsets)
    las.X, las.Y, las.Z = quantised.T
    values = dict(fields)
    if normals is not None:
        values.update(zip(_NORMALS, normals.T, strict=True))
    existing = set(header.point_format.dimension_names)
    clash = {"X", "Y", "Z"} & set(values)
    if clash:
        raise PointCloudFileError(f"{path}: field names {sorted(clash)} are the LAS integer "
                                  f"coordinates")
    new = [laspy.ExtraBytesParams(name, np.uint8 if v.dtype.kind == "b" else v.dtype,
                                  description="pssd_fast")
           for name, v in values.items() if name not in existing]
    long = [p.name for p in new if len(p.name.encode()) > 32]
    if long:
        raise PointCloudFileError(f"{path}: LAS extra dimension names are at most 32 bytes: "
                                  f"{long}")
    if new:
        las.add_extra_dims(new)
    for name, v in values.items():
        old = np.asarray(las[name])
        if name in existing and np.array_equal(old, v):
            continue  # untouched: leave the record bytes exactly as read
        try:
            las[name] = _fit(name, v, old.dtype, "its LAS dimension")
        except (ValueError, OverflowError) as exc:
            raise PointCloudFileError(f"{path}: {' '.join(str(exc).split())}") from None
    backend = laspy.LazBackend.LazrsParallel if compress else None
    return lambda fh: las.write(fh, do_compress=compress, laz_backend=backend)
