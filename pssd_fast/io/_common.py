"""What the format modules share: the cloud, the errors, argument checks and atomic writing."""
import importlib
import os
from dataclasses import dataclass, field

import numpy as np

from .. import atomic

COORDS = ("x", "y", "z")
NORMALS = ("nx", "ny", "nz")
INSTALL = "pip install 'pssd_fast[io]'"


class PointCloudFileError(ValueError):
    """A point-cloud file that cannot be read or written; the message names the file."""


class PointCloudFileNotFoundError(PointCloudFileError, FileNotFoundError):
    """The file to read, or the folder to write into, does not exist."""


class PointCloudWarning(UserWarning):
    """A note on a file: something of the cloud that the output format cannot hold and that is
    not written, or how a reader named columns that the file does not name."""


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
        object.__setattr__(self, "fields", as_fields(self.fields, len(points)))

    def __len__(self):
        return len(self.points)

    def __repr__(self):
        return (f"PointCloud(n={len(self)}, normals={self.normals is not None}, "
                f"fields={list(self.fields)}, format={self.format!r})")


@dataclass(frozen=True)
class Source:
    """Where a cloud was read from; subclasses add what its format needs to be written back."""

    # Absolute, so that writing onto the input is recognised from any folder; None for stdin.
    # Set by the dispatcher after the format module has read the data.
    path: str = field(default=None, kw_only=True)

    def take(self, rows):
        """This source for the cloud's ``rows`` only (formats with per-point records override
        it; the others keep nothing per point)."""
        return self

    def coordinates_dtype(self):
        """The dtype of the coordinates as the file holds them (float64 where they are text,
        scaled integers or doubles)."""
        return np.dtype(np.float64)


# ---------------------------------------------------------------------------------------------
# Argument checks


def check_finite(path, points):
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise PointCloudFileError(
            f"{path}: {int(bad.sum()):,} of {len(points):,} points have NaN or Inf coordinates "
            f"(the first is point {int(np.flatnonzero(bad)[0])})")


def as_array(path, values, name, shape):
    arr = np.asarray(values)
    if arr.shape != shape or arr.dtype.kind not in "fiu":
        raise PointCloudFileError(f"{path}: {name} must be a real array of shape {shape}; got "
                                  f"shape {arr.shape}, dtype {arr.dtype}")
    return arr.astype(np.float64)


def as_fields(fields, n):
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


def check_names(path, names, what):
    """Refuse names that would break a PLY header line or a text column line."""
    bad = [name for name in names if any(c.isspace() for c in name)]
    if bad:
        raise PointCloudFileError(f"{path}: {what} cannot hold names with spaces: {bad}")


def fit_dtype(name, values, dtype, where):
    """``values`` as ``dtype``; integer and bool targets must hold them exactly."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return values.astype(dtype)
    with np.errstate(invalid="ignore", over="ignore"):
        cast = values.astype(dtype)
    if not np.array_equal(cast, values):
        raise ValueError(f"field {name!r} does not fit the {dtype} type of {where}")
    return cast


def decimal_strings(values):
    """Decimal strings of ``values``: numpy prints the shortest string that reads back equal in
    the values' own dtype (integers without a decimal point, bool as 0 and 1)."""
    if values.dtype.kind == "b":
        values = values.astype(np.uint8)
    return values.astype(str).tolist()


def stream_size(fh):
    """Bytes from the start to the end of a seekable binary file object (left at the start)."""
    size = fh.seek(0, os.SEEK_END)
    fh.seek(0)
    return size


# ---------------------------------------------------------------------------------------------
# Writing and optional dependencies


def exists_message(path, cloud):
    src = cloud.source
    if (isinstance(src, Source) and src.path is not None and os.path.exists(src.path)
            and os.path.samefile(path, src.path)):
        return (f"{path}: is the file this cloud was read from; refusing to overwrite the input "
                f"(pass overwrite=True, --force on the command line, to replace it)")
    return (f"{path}: already exists; pass overwrite=True (--force on the command line) to "
            f"replace it")


def atomic_write(path, payload, overwrite, cloud):
    """Run ``payload(file)`` on a file that replaces ``path`` whole or not at all
    (:func:`pssd_fast.atomic.replacing`)."""
    message = exists_message(path, cloud) if path.exists() else None
    with atomic.replacing(path, overwrite=overwrite, exists_message=message) as fh:
        payload(fh)


def need(module, package, what):
    """Import an optional dependency, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"{what} needs {package}: {INSTALL}") from exc
