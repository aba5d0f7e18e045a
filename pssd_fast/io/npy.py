"""NumPy ``.npy`` arrays and ``.npz`` archives, with plain numpy (no pickled objects)."""
import io
import lzma
import math
import tokenize
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field

import numpy as np

from ._common import PointCloudFileError, Source, stream_size


@dataclass(frozen=True)
class _ArraySource(Source):
    dtype: np.dtype  # of the points array (npy: of the whole array), kept on write if float
    columns: int = 3  # npy: 3 (points) or 6 (points and normals)
    normals_dtype: np.dtype = None  # npz: of the normals array, likewise
    compressed: bool = False  # npz: zip-deflated members
    extras: dict = field(default_factory=dict)  # npz: arrays that are not per-point fields

    def coordinates_dtype(self):
        return np.dtype(np.float32) if self.dtype == np.float32 else np.dtype(np.float64)


def npy_header(path, fh, size, what):
    """Shape, Fortran order and dtype from an .npy header, checked against the ``size`` bytes
    available; a PointCloudFileError naming ``path`` and ``what`` otherwise."""
    fmt = np.lib.format
    try:
        with warnings.catch_warnings():
            # The header is a Python literal: a stray backslash in a corrupt one makes Python
            # warn of an "invalid escape sequence" (a SyntaxWarning from 3.12, a
            # DeprecationWarning before) before numpy refuses it.
            warnings.filterwarnings("ignore", "invalid escape sequence")
            version = fmt.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(fh)
            elif version == (2, 0):
                shape, fortran, dtype = fmt.read_array_header_2_0(fh)
            else:
                raise ValueError(f"unsupported .npy format version {version}")
    except (ValueError, tokenize.TokenError) as exc:  # numpy tokenizes old headers
        raise PointCloudFileError(f"{path}: {what} is not a valid .npy array "
                                  f"({' '.join(str(exc).split())})") from None
    if any(d < 0 for d in shape):
        raise PointCloudFileError(f"{path}: {what} claims shape {shape}, with a negative size")
    if dtype.hasobject:
        raise PointCloudFileError(f"{path}: {what} holds Python objects, which are not loaded")
    need = math.prod(shape) * dtype.itemsize
    have = size - fh.tell()
    if need > have:
        raise PointCloudFileError(f"{path}: {what} claims shape {shape} ({need:,} bytes) but "
                                  f"only {have:,} bytes follow its header (truncated)")
    return shape, fortran, dtype


def read(path, fh, ext):
    """Read an ``.npy`` array or an ``.npz`` archive, as the extension says.

    Parameters
    ----------
    path : pathlib.Path or str
        The file's name, for messages.
    fh : binary file object
        The data, seekable, at its start: a numeric (n, 3) or (n, 6) ``.npy`` array, or an
        ``.npz`` archive holding a numeric (n, 3) ``points`` array and optionally (n, 3)
        ``normals``.
    ext : str
        ``".npy"`` or ``".npz"``.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        As float64.
    normals : (n, 3) numpy.ndarray or None
        Columns 4-6 of an ``.npy`` array or the ``normals`` of an ``.npz``, as float64, or None.
    fields : dict of str to (n,) numpy.ndarray
        The other numeric or bool (n,) arrays of an ``.npz``; always empty for ``.npy``.
    source : object
        The array types (and for ``.npz`` the compression and the other arrays), for
        :func:`payload` to write back.

    Raises
    ------
    PointCloudFileError
        On a malformed, truncated or pickled array, a header claiming more bytes than the file
        holds (checked before anything is allocated), or arrays of the wrong shape or type.
    """
    return _read_npz(path, fh) if ext == ".npz" else _read_npy(path, fh)


def _read_npy(path, fh):
    shape, _, dtype = npy_header(path, fh, stream_size(fh), "the array")
    if len(shape) != 2 or shape[1] not in (3, 6) or dtype.kind not in "fiu":
        raise PointCloudFileError(f"{path}: expected an (n, 3) or (n, 6) numeric array; "
                                  f"got shape {shape}, dtype {dtype}")
    fh.seek(0)
    arr = np.lib.format.read_array(fh, allow_pickle=False)
    normals = arr[:, 3:].astype(np.float64) if shape[1] == 6 else None
    source = _ArraySource(arr.dtype, shape[1])
    return arr[:, :3].astype(np.float64), normals, {}, source


def _read_npz(path, fh):
    arrays = {}
    try:
        with zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
            for info in infos:
                key = info.filename.removesuffix(".npy")
                if key == info.filename:
                    raise PointCloudFileError(f"{path}: member {info.filename!r} is not an "
                                              f".npy array")
                # Decompressed whole, so that the header is checked against the bytes there
                # are, not against the size the archive claims.
                member = io.BytesIO(zf.read(info))
                npy_header(path, member, len(member.getvalue()), f"array {key!r}")
                member.seek(0)
                arrays[key] = np.lib.format.read_array(member, allow_pickle=False)
    except PointCloudFileError:
        raise
    # zipfile's errors: RuntimeError for an encrypted member, NotImplementedError for an
    # unknown compression, OSError for a bad bzip2 stream or offset.
    except (zipfile.BadZipFile, EOFError, ValueError, zlib.error, lzma.LZMAError, RuntimeError,
            NotImplementedError, OSError) as exc:
        raise PointCloudFileError(f"{path}: not a readable .npz (zip) archive, truncated or "
                                  f"corrupt ({' '.join(str(exc).split())})") from None
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
    source = _ArraySource(points.dtype, 3, None if normals is None else normals.dtype,
                          compressed, extras)
    normals = None if normals is None else normals.astype(np.float64)
    return points.astype(np.float64), normals, fields, source


def _float_dtype(dtype):
    """The input's float type, kept; integer arrays cannot hold moved points or normals."""
    return dtype if dtype is not None and dtype.kind == "f" else np.dtype(np.float64)


def payload(path, ext, points, normals, fields, source):
    """Prepare an ``.npy`` array or an ``.npz`` archive, as the extension says.

    Parameters
    ----------
    path : pathlib.Path or str
        The output's name, for messages.
    ext : str
        ``".npy"`` or ``".npz"``.
    points : (n, 3) numpy.ndarray
        Coordinates: the ``.npy`` array or the ``points`` of the ``.npz``, in the source's float
        type (float64 otherwise).
    normals : (n, 3) numpy.ndarray or None
        Normals, likewise in the source's float type: the ``normals`` of an ``.npz``, columns
        4-6 of an ``.npy`` only when the source was an (n, 6) ``.npy`` (an ``.npy`` holds
        points only otherwise, so that it stays the (n, 3) array tools expect).
    fields : dict of str to (n,) numpy.ndarray
        Arrays of the ``.npz`` in their own dtype; not written to ``.npy``.
    source : object or None
        What :func:`read` returned for an NPY or NPZ input (an ``.npz`` keeps its other arrays
        and its compression), or None.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given.

    Raises
    ------
    PointCloudFileError
        If a field of an ``.npz`` is named ``points`` or ``normals``.
    """
    dtype = _float_dtype(source.dtype if source is not None else None)
    if ext != ".npz":
        six = normals is not None and source is not None and source.columns == 6
        arr = np.hstack([points, normals]) if six else points
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
