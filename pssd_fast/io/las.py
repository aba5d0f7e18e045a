"""LAS and LAZ files through ``laspy[lazrs]``: header, VLRs, EVLRs and point records kept."""
import copy
import dataclasses
from dataclasses import dataclass

import numpy as np

from ._common import INSTALL, NORMALS, PointCloudFileError, Source, fit_dtype, need, stream_size

# LAS point records are read in pieces so that a header claiming more points than the file
# holds costs at most one piece of memory before the shortfall is noticed.
_LAS_CHUNK = 2**20


@dataclass(frozen=True)
class _LasSource(Source):
    header: object  # laspy.LasHeader, VLRs and EVLRs included; deep-copied before each write
    records: np.ndarray  # the raw point records (structured array of the point format)

    def take(self, rows):
        return dataclasses.replace(self, records=self.records[rows])


def _need_laspy(ext, what):
    laspy = need("laspy", "laspy[lazrs]", f"{what} .las/.laz files")
    if ext == ".laz" and not laspy.LazBackend.LazrsParallel.is_available():
        raise ImportError(f"{what} .laz files needs laspy[lazrs] (the lazrs backend): "
                          f"{INSTALL}")
    return laspy


def read(path, fh, ext):
    """Read a LAS or LAZ file.

    Parameters
    ----------
    path : pathlib.Path or str
        The file's name, for messages.
    fh : binary file object
        The data, seekable, at its start.
    ext : str
        ``".las"`` or ``".laz"``.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        The integer coordinates times the header's scale plus its offset, as float64.
    normals : (n, 3) numpy.ndarray or None
        The ``nx``/``ny``/``nz`` extra bytes as float64, or None if one is missing.
    fields : dict of str to (n,) numpy.ndarray
        Every other dimension holding one value per point (standard or extra bytes).
    source : object
        The header (VLRs and EVLRs included) and the raw point records, for :func:`payload`
        to write back.

    Raises
    ------
    PointCloudFileError
        On a truncated or corrupt file, or a header claiming more points than the file holds
        (checked before the records are allocated).
    ImportError
        If ``laspy`` is not installed, or a ``.laz`` file lacks its lazrs backend.
    """
    laspy = _need_laspy(ext, "Reading")
    # laspy's own errors, lazrs' (RuntimeError) and struct/EOF errors of a short header.
    failures = (laspy.LaspyException, RuntimeError, ValueError, EOFError)

    def corrupt(exc):
        return PointCloudFileError(f"{path}: cannot read LAS/LAZ data (truncated or corrupt "
                                   f"file): {' '.join(str(exc).split())}")

    size = stream_size(fh)
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
    if all(c in values for c in NORMALS):
        normals = np.column_stack([values.pop(c) for c in NORMALS]).astype(np.float64)
    return points, normals, values, _LasSource(header, records)


def describe(source):
    """Lines naming a LAS file's version, point format, scale, offset and VLR counts."""
    header = source.header

    def exact(values):
        return "(" + ", ".join(np.format_float_positional(v, trim="-") for v in values) + ")"

    return [f"LAS {header.version}, point format {header.point_format.id}, scale "
            f"{exact(header.scales)}, offset {exact(header.offsets)}, {len(header.vlrs)} VLRs, "
            f"{len(header.evlrs or [])} EVLRs"]


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


def _extra_type(name, values):
    """Type of a new extra dimension: its own (bool as uint8); new normals as float32, whose
    precision (6e-8) a unit vector does not need doubled at 12 more bytes per point."""
    if name in NORMALS:
        return np.float32
    return np.uint8 if values.dtype.kind == "b" else values.dtype


def new_dims(laspy, path, existing, values):
    """The extra dimensions to add for the names of ``values`` not in ``existing``."""
    new = [laspy.ExtraBytesParams(name, _extra_type(name, v), description="pssd_fast")
           for name, v in values.items() if name not in existing]
    long = [p.name for p in new if len(p.name.encode()) > 32]
    if long:
        raise PointCloudFileError(f"{path}: LAS extra dimension names are at most 32 bytes: "
                                  f"{long}")
    return new


def put_values(path, records, existing, values):
    """``values`` into the dimensions of ``records`` (LasData or a point record) by name."""
    for name, v in values.items():
        old = np.asarray(records[name])
        if name in existing and np.array_equal(old, v):
            continue  # untouched: leave the record bytes exactly as read
        try:
            records[name] = fit_dtype(name, v, old.dtype, "its LAS dimension")
        except (ValueError, OverflowError) as exc:
            raise PointCloudFileError(f"{path}: {' '.join(str(exc).split())}") from None


def payload(path, ext, points, normals, fields, source):
    """Prepare a LAS file (LAZ, compressed by lazrs, for ``.laz``).

    Parameters
    ----------
    path : pathlib.Path or str
        The output's name, for messages.
    ext : str
        ``".las"`` or ``".laz"`` (compressed).
    points : (n, 3) numpy.ndarray
        Coordinates, quantised with the source's scale and offset (for a new file: LAS 1.4,
        point format 6, offset the bounding-box centre, per-axis scale the smallest power of
        ten that keeps the extent inside int32).
    normals : (n, 3) numpy.ndarray or None
        Normals, written to the ``nx``/``ny``/``nz`` dimensions (float32 extra bytes if new).
    fields : dict of str to (n,) numpy.ndarray
        Dimensions; one the point format or source has must fit its type exactly unless it
        is a float type, others become extra bytes of their own dtype (bool as uint8).
    source : object or None
        What :func:`read` returned for a LAS/LAZ input (its header, VLRs, EVLRs and every
        untouched record byte are kept), or None.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given.

    Raises
    ------
    PointCloudFileError
        If coordinates do not fit the int32 range, a field is named ``X``, ``Y`` or ``Z``, a
        new name is longer than 32 bytes, or a value does not fit its dimension.
    ImportError
        If ``laspy`` is not installed, or ``.laz`` output lacks its lazrs backend.
    """
    laspy = _need_laspy(ext, "Writing")
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
        values.update(zip(NORMALS, normals.T, strict=True))
    existing = set(header.point_format.dimension_names)
    clash = {"X", "Y", "Z"} & set(values)
    if clash:
        raise PointCloudFileError(f"{path}: field names {sorted(clash)} are the LAS integer "
                                  f"coordinates")
    new = new_dims(laspy, path, existing, values)
    if new:
        las.add_extra_dims(new)
    put_values(path, las, existing, values)
    compress = ext == ".laz"
    backend = laspy.LazBackend.LazrsParallel if compress else None
    return lambda fh: las.write(fh, do_compress=compress, laz_backend=backend)
