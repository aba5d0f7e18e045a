"""Reading and writing point-cloud files without losing what the scanner put in them.

:func:`read` turns a ``.ply``, ``.xyz``/``.pts``/``.txt``/``.csv``, ``.obj``, ``.npy``, ``.npz`` or
``.las``/``.laz`` file (text, PLY and OBJ also gzipped: ``scan.ply.gz``), or standard input
(``"-"`` with ``format=``), into a :class:`PointCloud`: float64 points, normals when the file has
them, and every other per-point attribute (colours, intensity, classification, scalar fields...) in
``fields`` with its original dtype. :func:`write` writes a cloud back with new points, normals and
added per-point fields (``likelihood``, ``feature_intensity``...), keeping everything else of the
input as it was when the output has the input's format: other PLY properties and elements (faces),
comments, ASCII/binary and byte order; LAS point format, version, scale, offset, every point
record, VLRs and EVLRs; leading comment lines of text files; other arrays of an ``.npz``; faces,
groups, materials and every other line of an OBJ file.

What cannot be carried across formats (the output format follows the output's extension):

* PLY elements other than ``vertex`` (faces, edges...), PLY comments and ``obj_info``, list
  properties of vertices, and LAS headers, VLRs, EVLRs and multi-valued extra bytes exist only
  in their own format; writing to another format drops them.
* ``.npy`` holds points only, an (n, 3) array (normals as columns 4-6 only when the input was
  an (n, 6) ``.npy``); OBJ holds ``red green blue`` (or ``w``) on its ``v`` lines, colours as
  0-1 floats (integer colours divided by 255, or 65535 above 255), and normals as ``vn``
  lines. Fields these cannot hold are dropped with a :class:`PointCloudWarning`
  (use ``.npz`` to keep them as named arrays).
* Text files store every column as a decimal number: a column written without decimal point or
  exponent comes back as integers (colours as uint8), others as float64; each value is written
  in the shortest form that reads back equal in its own dtype. Only comment lines before the
  data are kept. ``.csv`` output is comma-separated with a bare ``x,y,z,...`` header line;
  ``.pts`` output always starts with the point count line, then ``x y z intensity red green
  blue`` (those the cloud has) before other columns, and gets a ``# x y z ...`` column line
  only when the column names differ from what a reader infers by default.
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
import dataclasses
import gzip
import io
import os
import sys
import warnings
import zlib
from pathlib import Path

import numpy as np

from . import las, npy, obj, ply, text
from ._common import (COORDS, NORMALS, PointCloud, PointCloudFileError,
                      PointCloudFileNotFoundError, PointCloudWarning, Source, as_array, as_fields,
                      atomic_write, check_finite, check_names, exists_message)

# Report the public classes where users import them from, not from the private module.
for _cls in (PointCloud, PointCloudFileError, PointCloudFileNotFoundError, PointCloudWarning):
    _cls.__module__ = __name__
del _cls

__all__ = ["STDIO", "PointCloud", "PointCloudFileError", "PointCloudFileNotFoundError",
           "PointCloudWarning", "describe", "formats", "holds_normals", "read", "select",
           "storable", "stored", "write"]

#: The path that means standard input (:func:`read`) or standard output (:func:`write`).
STDIO = "-"
# Extension -> PointCloud.format, and the module reading and writing each format.
_FORMATS = {".csv": "xyz", ".las": "las", ".laz": "las", ".npy": "npy", ".npz": "npz",
            ".obj": "obj", ".ply": "ply", ".pts": "xyz", ".txt": "xyz", ".xyz": "xyz"}
_MODULES = {"las": las, "npy": npy, "npz": npy, "obj": obj, "ply": ply, "xyz": text}
# Formats that may be gzipped (the others are binary, and LAZ and NPZ compress themselves).
_GZIP_KINDS = ("obj", "ply", "xyz")
# Fields each extension can hold, where not all.
_HOLDS = {".npy": (), ".obj": obj.FIELDS}


@dataclasses.dataclass(frozen=True)
class _Target:
    name: object  # the Path, or "<stdin>"/"<stdout>": what messages name
    ext: str  # the format's extension, lower case, without .gz
    gz: bool
    path: Path = None  # None for stdin/stdout


def formats():
    """List the file extensions :func:`read` and :func:`write` understand.

    Returns
    -------
    tuple of str
        Lower-case extensions with their dot, sorted: ``.csv .las .laz .npy .npz .obj .ply
        .pts .txt .xyz``, and the gzipped ``.csv.gz .obj.gz .ply.gz .pts.gz .txt.gz .xyz.gz``.
        Matching is case-insensitive. The same names without the dot (``"xyz"``,
        ``"ply.gz"``) are the values of ``format=``.
    """
    gz = [ext + ".gz" for ext, kind in _FORMATS.items() if kind in _GZIP_KINDS]
    return tuple(sorted([*_FORMATS, *gz]))


def holds_normals(path, cloud, *, format=None):
    """Whether :func:`write` stores normals in ``path`` (``format`` as it takes it): every
    format does but ``.npy``, which holds them only where ``cloud`` came from an (n, 6)
    ``.npy`` (columns 4-6)."""
    if _target(path, format, "<stdout>").ext != ".npy":
        return True
    return cloud.format == "npy" and getattr(cloud.source, "columns", 3) == 6


def storable(path, names, *, format=None):
    """The names among ``names`` whose per-point fields :func:`write` can store in ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        An output file name (or ``"-"`` with ``format``); only its extension matters.
    names : iterable of str
        Field names.
    format : str, optional
        As for :func:`write`.

    Returns
    -------
    list of str
        ``names`` in their order, less those the format cannot hold (all of them for
        ``.npy``, all but ``red green blue w`` for ``.obj``).

    Raises
    ------
    PointCloudFileError
        On an unknown extension or format.
    """
    holds = _HOLDS.get(_target(path, format, "<stdout>").ext)
    return [name for name in names if holds is None or name in holds]


def _split_ext(name, ext, what):
    """(format extension, gzipped) of a lower-case extension such as ``.ply`` or ``.ply.gz``."""
    gz = ext.endswith(".gz") and ext != ".gz"
    base = ext.removesuffix(".gz") if gz else ext
    if base not in _FORMATS:
        raise PointCloudFileError(f"{name}: {what}; supported: {', '.join(formats())}")
    if gz and _FORMATS[base] not in _GZIP_KINDS:
        gzipped = ", ".join(e for e in formats() if e.endswith(".gz"))
        raise PointCloudFileError(f"{name}: {base} files cannot be gzipped (only text, PLY and "
                                  f"OBJ files: {gzipped})")
    return base, gz


def _target(path, format, stream):
    """Where to read or write: a file, or stdin/stdout (``stream``) for ``"-"``."""
    stdio = isinstance(path, (str, os.PathLike)) and os.fspath(path) == STDIO
    name = stream if stdio else Path(os.fspath(path))
    if not stdio and name.is_dir():  # before its name's extension is read
        raise PointCloudFileError(f"{name}: is a directory, not " + (
            "a point-cloud file" if stream == "<stdin>" else "a file name"))
    if format is not None:
        ext = "." + str(format).lower().lstrip(".")
        return _Target(name, *_split_ext(name, ext, f"unknown format {format!r}"),
                       None if stdio else name)
    if stdio:
        raise PointCloudFileError(f"{name}: reading or writing '-' needs a format (format='xyz', "
                                  f"--format xyz on the command line)")
    lower = name.name.lower()
    ext = name.suffix.lower()
    if ext == ".gz":
        ext = Path(lower[:-3]).suffix + ".gz"
    shown = "".join(name.suffixes[-2:]) if ext.endswith(".gz") else name.suffix
    what = f"unknown extension {shown!r}" if shown else "no extension"
    return _Target(name, *_split_ext(name, ext, what), name)


def _gunzip(name, raw):
    try:
        return gzip.decompress(raw)
    except (gzip.BadGzipFile, EOFError, zlib.error) as exc:
        raise PointCloudFileError(f"{name}: not a complete gzip file ({exc})") from None


def read(path, *, format=None, columns=None):
    r"""Read a point-cloud file, or standard input.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply`` (ASCII or binary), ``.xyz``/``.pts``/``.txt``/``.csv`` (text columns),
        ``.obj``, ``.npy``, ``.npz`` or ``.las``/``.laz`` file; text, PLY and OBJ may be
        gzipped (``scan.ply.gz``). The extension picks the reader (case-insensitive). ``"-"``
        reads standard input, whose format ``format`` must name.
    format : str, optional
        The format, as an extension with or without its dot (``"xyz"``, ``"ply.gz"``), used
        instead of the name's extension; needed for ``"-"``.
    columns : str or sequence of str, optional
        Text files only: the names of the columns in their order (``"x,y,z,red,green,blue"``
        or a list), every column once with ``x y z`` among them; they win over a column-name
        line in the file (a :class:`PointCloudWarning` says so where they differ).

    Returns
    -------
    PointCloud
        The file's content, in these attributes:

        - ``points``: the (n, 3) coordinates as float64, in the file's order (LAS: with the
          header's scale and offset applied, in the file's units).
        - ``normals``: (n, 3) float64 from PLY ``nx ny nz``, text ``nx ny nz`` columns (columns
          4-6 of a six-column text file without names where they are unit vectors, see
          Notes), OBJ ``vn`` lines (one per vertex), the columns 4-6 of an ``.npy`` array, the
          ``normals`` key of an ``.npz`` or ``nx``/``ny``/``nz`` LAS extra bytes; None when the
          file has none.
        - ``fields``: every other per-point attribute, a dict of (n,) arrays by name, each
          with its dtype: PLY vertex properties (``red``, ``quality``...), LAS dimensions
          (``intensity``, ``classification``, ``gps_time``...) and extra bytes, text columns
          (named as the file's column line names them, common spellings mapped to ``red``,
          ``intensity``..., see Notes), OBJ colours, the other per-point arrays of an
          ``.npz``.
        - ``format``: ``"ply"``, ``"xyz"`` (every text format), ``"obj"``, ``"npy"``,
          ``"npz"`` or ``"las"`` (also LAZ).
        - ``source``: the rest of the file, kept for :func:`write` (the PLY header and other
          elements, the LAS header with its VLRs and point records, leading comment lines of
          text...); opaque, and :func:`describe` says what it holds.

    Raises
    ------
    PointCloudFileNotFoundError
        If the file does not exist (it is also a ``FileNotFoundError``).
    PointCloudFileError
        On an unknown extension or format, a directory, malformed or truncated content
        (gzip included), a header that claims more points than the file can hold (checked
        before anything is allocated), NaN or Inf coordinates, or no points at all. The
        message is one line naming the file.
    TypeError
        If ``columns`` is not a string or a sequence of strings.
    ImportError
        If ``plyfile`` (PLY) or ``laspy[lazrs]`` (LAS/LAZ) is not installed.

    Warns
    -----
    PointCloudWarning
        How the columns 4-6 of a six-column text file without names were read, and where
        ``columns`` replaces other names of the file's column-name line.

    Notes
    -----
    Text files: columns are separated by commas, semicolons, tabs or spaces (detected); ``#``
    starts a comment, and so does ``//`` before the data; a first line holding a single
    integer is a point count (as in PTS files) and must match the number of rows. The last
    line before the data names the columns when it is a header (``x,y,z,r,g,b``, ``//X Y Z``,
    ``# x y z nx ny nz likelihood``, as :func:`write` puts it); names are case-insensitive and
    common spellings map to ``x y z nx ny nz red green blue intensity`` (``R``, ``Nx``,
    ``scalar_Intensity``...). Without names (nor ``columns``), three columns are points;
    ``.pts`` files of 4 or 7 columns are ``x y z intensity [red green blue]``; columns 4-6 of
    a six-column file are ``red green blue`` where all three are written as integers (no
    decimal point or exponent) from 0 to 65535, else ``nx ny nz`` where every row is a unit
    vector (length within 5% of 1) or has no normal (NaN or ``0 0 0``), else fields ``col3``
    to ``col5``, and a :class:`PointCloudWarning` says which; other counts are points
    followed by fields ``col3``, ``col4``...

    Examples
    --------
    A text file with a comment line and named columns (a ``.ply`` or ``.las`` file is read
    the same way):

    >>> import tempfile
    >>> from pathlib import Path
    >>> from pssd_fast import io
    >>> folder = tempfile.TemporaryDirectory()
    >>> path = Path(folder.name, "scan.txt")
    >>> _ = path.write_text("// from the scanner\nX Y Z Nx Ny Nz Intensity\n"
    ...                     "0 0 0 0 0 1 7\n1 0 0.5 0 0 1 8\n0 1 0.25 0 0 1 9\n")
    >>> cloud = io.read(path)
    >>> cloud
    PointCloud(n=3, normals=True, fields=['intensity'], format='xyz')
    >>> cloud.points.dtype, cloud.points[1].tolist(), cloud.normals[1].tolist()
    (dtype('float64'), [1.0, 0.0, 0.5], [0.0, 0.0, 1.0])
    >>> cloud.fields["intensity"].tolist()
    [7, 8, 9]
    >>> folder.cleanup()
    """
    target = _target(path, format, "<stdin>")
    name = target.name
    kind = _FORMATS[target.ext]
    if columns is not None:
        columns = _column_list(columns)
        if kind != "xyz":
            raise PointCloudFileError(f"{name}: columns= names the columns of text files "
                                      f"(.xyz .pts .txt .csv); a {target.ext} file names its own")
    options = {} if columns is None else {"columns": columns}
    if target.path is None:
        data = sys.stdin.buffer.read()
        fh = io.BytesIO(_gunzip(name, data) if target.gz else data)
    else:
        if not name.exists():
            raise PointCloudFileNotFoundError(f"{name}: no such file")
        if name.is_dir():
            raise PointCloudFileError(f"{name}: is a directory, not a point-cloud file")
        fh = open(name, "rb")
        if target.gz:
            with fh:
                fh = io.BytesIO(_gunzip(name, fh.read()))
    # Casting a signalling NaN sets numpy's "invalid" flag, and a LAS scale of 1e300 its
    # "overflow"; NaN and Inf coordinates are refused below with a message of their own, and
    # NaN normals and fields are kept as they are.
    with fh, np.errstate(invalid="ignore", over="ignore"):
        points, normals, fields, source = _MODULES[kind].read(name, fh, target.ext, **options)
    if len(points) == 0:
        raise PointCloudFileError(f"{name}: holds no points")
    check_finite(name, points)
    if target.path is not None:
        source = dataclasses.replace(source, path=os.path.abspath(target.path))
    return PointCloud(points, normals, fields, kind, source)


def _column_list(columns):
    """``columns`` of :func:`read` as a list of names: a comma-separated string split."""
    if isinstance(columns, str):
        columns = columns.split(",")
    try:
        names = list(columns)
    except TypeError:
        names = None
    if names is None or not all(isinstance(c, str) for c in names):
        raise TypeError(f"columns must be a comma-separated string or a sequence of strings; "
                        f"got {columns!r}")
    return names


def write(path, cloud, *, points=None, normals=None, fields=None, overwrite=False, format=None):
    r"""Write a point cloud, atomically, in the format of the output's extension.

    Parameters
    ----------
    path : str or os.PathLike
        The output file; its extension (see :func:`formats`) picks the format, and a ``.gz``
        after it (text, PLY, OBJ) gzips it. ``"-"`` writes to standard output in the format
        ``format`` names.
    cloud : PointCloud, DenoiseResult or (n, 3) array_like
        The cloud to write, usually from :func:`read` (its ``points``, ``normals``, ``fields``
        and, into its own format, the rest of its file), or built in memory
        (``PointCloud(points, normals, fields)``); a result of :func:`pssd_fast.denoise` is
        its points and normals, an array its points alone.
    points : (n, 3) array_like, optional
        Coordinates replacing ``cloud.points`` (same number of points).
    normals : (n, 3) array_like, optional
        Normals replacing ``cloud.normals``.
    fields : dict of str to (n,) array_like, optional
        Per-point values added as new properties (PLY), columns (text), arrays (NPZ) or extra
        bytes (LAS), each with its own dtype (pass float32 arrays for compact files). A name
        the cloud already has replaces that attribute's values, which must then fit its
        stored type exactly unless it is a float type. Names may not contain whitespace nor be
        ``x y z nx ny nz``.
    overwrite : bool, default False
        Replace an existing file, the input file of ``cloud`` included.
    format : str, optional
        The format, as an extension with or without its dot (``"xyz"``, ``"ply.gz"``), used
        instead of the name's extension; needed for ``"-"``.

    Returns
    -------
    pathlib.Path or str
        The file written, or ``"-"`` for standard output.

    Raises
    ------
    TypeError
        If ``cloud`` is none of the kinds above.
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    PointCloudFileError
        On an unknown extension or format, a directory as ``path``, NaN or Inf coordinates,
        arrays of the wrong shape or values that do not fit the output (a subclass of
        ``ValueError``).
    ImportError
        If ``plyfile`` (PLY) or ``laspy[lazrs]`` (LAS/LAZ) is not installed.

    Warns
    -----
    PointCloudWarning
        When ``.npy`` or ``.obj`` output cannot hold some of the fields, or ``.npy`` output
        the normals (:func:`holds_normals`; they are not written).

    Notes
    -----
    When the output has the format of ``cloud``'s source file, everything of that file is
    written back unchanged except the coordinates, normals and fields given (see the module
    documentation for what other formats cannot hold). The data goes to a temporary file in
    the output's folder that is renamed onto ``path`` only once complete; on any error it is
    removed and ``path`` is left as it was. Standard output gets the data in one piece once it
    is complete. The input file is never opened for writing.

    Examples
    --------
    New coordinates and a new field written into a file of the input's format, which keeps
    the input's comment line and intensity column:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from pssd_fast import io
    >>> folder = tempfile.TemporaryDirectory()
    >>> scan, clean = Path(folder.name, "scan.txt"), Path(folder.name, "clean.txt")
    >>> _ = scan.write_text("// from the scanner\nx y z intensity\n"
    ...                     "0 0 0 7\n1 0 0.5 8\n0 1 0.25 9\n")
    >>> cloud = io.read(scan)
    >>> out = io.write(clean, cloud, points=cloud.points + [0, 0, 1],
    ...                fields={"likelihood": np.array([1.0, 0.5, 0.25])})
    >>> print(out.read_text(), end="")
    // from the scanner
    # x y z intensity likelihood
    0.0 0.0 1.0 7 1.0
    1.0 0.0 1.5 8 0.5
    0.0 1.0 1.25 9 0.25
    >>> io.read(out).fields["likelihood"].tolist()
    [1.0, 0.5, 0.25]

    An existing file is replaced only when asked:

    >>> io.write(out, cloud)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    FileExistsError: ...clean.txt: already exists; pass overwrite=True (--force on the ...
    >>> io.write(out, cloud, overwrite=True) == out
    True
    >>> folder.cleanup()
    """
    cloud = _as_cloud(cloud)
    target = _target(path, format, "<stdout>")
    name = target.name
    if target.path is not None:
        if not name.parent.is_dir():
            raise PointCloudFileNotFoundError(f"{name}: folder {name.parent} does not exist")
        if name.is_dir():
            raise PointCloudFileError(f"{name}: is a directory, not a file name")
        if not overwrite and name.exists():
            raise FileExistsError(exists_message(name, cloud))
    n = len(cloud)
    pts = cloud.points if points is None else as_array(name, points, "points", (n, 3))
    check_finite(name, pts)
    nrm = cloud.normals if normals is None else as_array(name, normals, "normals", (n, 3))
    try:
        new = as_fields(fields or {}, n)
    except ValueError as exc:
        raise PointCloudFileError(f"{name}: {exc}") from None
    check_names(name, new, "field names")
    reserved = sorted(set(new) & set(COORDS + NORMALS))
    if reserved:
        raise PointCloudFileError(f"{name}: field names {reserved} are reserved for the "
                                  f"coordinates and normals (pass points= or normals=)")
    merged = {**cloud.fields, **new}
    kind = _FORMATS[target.ext]
    if kind in ("ply", "xyz"):
        check_names(name, merged, f"a {target.ext} file")
    source = cloud.source if cloud.format == kind else None
    kept = storable(name, merged, format=target.ext)
    dropped = [f for f in merged if f not in kept]
    lost = (["normals"] if nrm is not None and not holds_normals(name, cloud,
                                                                 format=target.ext) else []) + (
        [f"fields {dropped}"] if dropped else [])
    if lost:
        warnings.warn(f"{name}: {target.ext} cannot hold {' or '.join(lost)}; they are not "
                      f"written (use .npz, .ply, .las or text to keep them)", PointCloudWarning,
                      stacklevel=2)
    payload = _MODULES[kind].payload(name, target.ext, pts, nrm, merged, source)
    if target.gz:
        payload = _gzipped(payload)
    if target.path is None:
        buffer = io.BytesIO()
        payload(buffer)
        left = buffer.getbuffer()
        while left:
            # A pipe whose reader went away takes part of a large write and says how much;
            # the next write raises (BrokenPipeError) rather than the output ending unseen.
            left = left[sys.stdout.buffer.write(left):]
        sys.stdout.buffer.flush()
        return STDIO
    atomic_write(name, payload, overwrite, cloud)
    return name


def _as_cloud(cloud):
    """``cloud`` as :func:`write` takes it, a :class:`PointCloud`."""
    if isinstance(cloud, PointCloud):
        return cloud
    if all(hasattr(cloud, name) for name in ("points", "normals", "stats")):  # a result
        return PointCloud(cloud.points, cloud.normals)
    points = np.asarray(cloud) if isinstance(cloud, (np.ndarray, list, tuple)) else None
    if (points is None or points.ndim != 2 or points.shape[-1] != 3
            or points.dtype.kind not in "fiu"):
        shape = "" if points is None else f" of shape {points.shape}, dtype {points.dtype}"
        raise TypeError(f"cloud must be a pssd_fast.io.PointCloud, a denoise result or an "
                        f"(n, 3) array of coordinates; got {type(cloud).__name__}{shape}")
    return PointCloud(points)


def stored(path, cloud, points, *, format=None):
    """The coordinates that :func:`write` (``write(path, cloud, points=points)``) stores:
    LAS and LAZ files round them to the scale of their header (the source's, where ``cloud``
    came from one); the other formats store them as given.

    Parameters
    ----------
    path : str or os.PathLike
        The output, as :func:`write` takes it.
    cloud : PointCloud
        What :func:`read` returned.
    points : (n, 3) array_like
        The coordinates to write.
    format : str, optional
        As :func:`write` takes it.

    Returns
    -------
    (n, 3) numpy.ndarray
        float64.
    """
    target = _target(path, format, "<stdout>")
    pts = np.asarray(points, np.float64)
    if _FORMATS[target.ext] != "las":
        return pts
    return las.stored(target.name, pts, cloud.source if cloud.format == "las" else None)


def describe(cloud):
    """What a cloud's file holds beyond points, normals and fields, for people to read.

    Parameters
    ----------
    cloud : PointCloud
        A cloud from :func:`read`.

    Returns
    -------
    list of str
        One line per item: a PLY or OBJ file's other elements with their counts (faces...);
        a LAS file's version, point format, scale, offset and VLR counts. Empty for other
        formats and for clouds built in memory.
    """
    module = _MODULES[cloud.format]
    if cloud.source is None or not hasattr(module, "describe"):
        return []
    return module.describe(cloud.source)


def select(cloud, rows):
    """The cloud's ``rows`` only, with everything :func:`write` keeps of its source file.

    Parameters
    ----------
    cloud : PointCloud
        A cloud from :func:`read`.
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


def _gzipped(payload):
    """``payload`` writing through gzip; no name or time stamp, so equal data give equal files.
    Level 6 (zlib's and gzip's default): level 9 compresses a scan's text about 1% smaller and
    5 times slower, longer than reading and writing the file take."""
    def write(fh):
        with gzip.GzipFile(filename="", mode="wb", fileobj=fh, mtime=0, compresslevel=6) as gz:
            payload(gz)
    return write
