"""LAS and LAZ files through ``laspy[lazrs]``: header, VLRs, EVLRs and point records kept."""
import copy
import dataclasses
import struct
from dataclasses import dataclass

import numpy as np

from .._validation import mean_spacing
from ._common import INSTALL, NORMALS, PointCloudFileError, Source, fit_dtype, need, stream_size

# LAS point records are read in pieces, the first of 4 MiB and each next as large as all read
# so far (up to _LAS_CHUNK records), so that a header claiming more points than the file holds
# costs little more memory than the points there are before the shortfall is noticed.
_LAS_FIRST_BYTES = 2**22
_LAS_CHUNK = 2**20
# The smallest public header of each LAS 1.x version, and the fixed part of a VLR and an EVLR.
_LAS_HEADER_SIZES = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
_VLR_HEADER = 54
_EVLR_HEADER = 60
# The laszip VLR: its compressors that chunk the points (pointwise, layered), the chunk size
# meaning chunks of their own sizes, and where its items start (type, size, version each).
_LAZ_CHUNKED = (2, 3)
_LAZ_LAYERED = 3
_LAZ_VARIABLE = 2**32 - 1
_LAZ_ITEMS = 34
# Layers of a layered chunk per item type (point14, rgb14, rgbnir14, wavepacket14); byte14
# items have one a byte.
_LAZ_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}
_LAZ_BYTES = 14


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


def check_header(path, fh, size):
    """Refuse a LAS header whose sizes and counts do not fit the ``size`` bytes of the file;
    ``fh`` is left at its start.

    laspy reads the header, the VLRs and the EVLRs where and as many as the header says: a
    wrong offset makes it allocate that many bytes, and a wrong count loops that many times.
    Uncompressed points must fit too; compressed ones are read in growing pieces instead
    (docs/DECISIONS.md, "Readers that survive any file").
    """
    try:
        _check_header(path, fh, size)
    finally:
        fh.seek(0)


def _check_header(path, fh, size):
    """:func:`check_header`, leaving ``fh`` anywhere."""
    head = fh.read(_LAS_HEADER_SIZES[4])
    fh.seek(0)
    if len(head) < _LAS_HEADER_SIZES[0] or not head.startswith(b"LASF"):
        raise PointCloudFileError(f"{path}: not a LAS file (no 'LASF' signature and header)")
    major, minor = head[24], head[25]
    if major != 1 or minor not in _LAS_HEADER_SIZES:
        raise PointCloudFileError(f"{path}: LAS version {major}.{minor} is not 1.0 to 1.4")
    header_size, offset, vlrs = struct.unpack_from("<HII", head, 94)
    if not _LAS_HEADER_SIZES[minor] <= header_size <= offset <= size:
        raise PointCloudFileError(
            f"{path}: LAS {major}.{minor} header of {header_size:,} bytes with its points at "
            f"byte {offset:,} does not fit the file's {size:,} bytes (corrupt header)")
    if header_size + vlrs * _VLR_HEADER > offset:
        raise PointCloudFileError(f"{path}: header claims {vlrs:,} VLRs, more than the "
                                  f"{offset - header_size:,} bytes before the points hold")
    point_format, record = struct.unpack_from("<BH", head, 104)
    n = struct.unpack_from("<Q" if minor >= 4 else "<I", head, 247 if minor >= 4 else 107)[0]
    need = offset + n * record
    if point_format & 0xC0 == 0x80:  # compressed (laspy's test)
        _check_laz(path, fh, header_size, vlrs, offset, n, size)
    elif need > size:
        raise PointCloudFileError(
            f"{path}: header claims {n:,} points ({need:,} bytes with the header) but the "
            f"file has {size:,} bytes (truncated file or wrong header)")
    if minor < 4:
        return
    start, evlrs = struct.unpack_from("<QI", head, 235)
    if evlrs and (start < offset or start + evlrs * _EVLR_HEADER > size):
        raise PointCloudFileError(f"{path}: header claims {evlrs:,} EVLRs from byte {start:,}, "
                                  f"which do not fit after the points of a file of {size:,} "
                                  f"bytes (truncated file or wrong header)")
    for i in range(evlrs):  # at most size / 60 of them, as checked above
        fh.seek(start + 20)  # its record length, after the reserved field and the ids
        length = fh.read(8)
        start += _EVLR_HEADER + (struct.unpack("<Q", length)[0] if len(length) == 8 else size)
        if start > size:
            raise PointCloudFileError(f"{path}: EVLR {i + 1} of {evlrs:,} ends beyond the end "
                                      f"of the file (truncated file or wrong header)")


def _laszip_vlr(fh, header_size, vlrs):
    """The record of a LAS file's "laszip encoded" VLR, or None."""
    at = header_size
    for _ in range(vlrs):
        fh.seek(at)
        head = fh.read(_VLR_HEADER)
        if len(head) < _VLR_HEADER:
            return None
        record_id, length = struct.unpack_from("<HH", head, 18)
        if head[2:18].rstrip(b"\0") == b"laszip encoded" and record_id == 22204:
            return fh.read(length)
        at += _VLR_HEADER + length
    return None


def _check_laz(path, fh, header_size, vlrs, start, n, size):
    """Refuse a LAZ file whose chunks do not fit it or its header.

    lazrs allocates what the file claims before reading it: the chunk table's entries, the
    points of a fixed-size chunk, each chunk's bytes and each layer's bytes. On files of 1.6 kB
    such claims allocated 4 GB, aborted the process (52 and 180 GB) or raised a Rust panic.
    """
    record = _laszip_vlr(fh, header_size, vlrs)
    if record is None or len(record) < _LAZ_ITEMS:
        return  # laspy and lazrs refuse a LAZ file without a whole laszip VLR
    compressor = struct.unpack_from("<H", record)[0]
    chunk_size = struct.unpack_from("<I", record, 12)[0]
    if compressor not in _LAZ_CHUNKED:
        return  # lazrs reads no other
    fh.seek(start)  # the points start with the chunk table's offset...
    table = struct.unpack("<q", fh.read(8).ljust(8, b"\0"))[0]
    if table == -1:  # ...or, from a writer that could not seek back, end with it
        fh.seek(max(size - 8, 0))
        table = struct.unpack("<q", fh.read(8).ljust(8, b"\0"))[0]
    if not start + 8 <= table <= size - 8:
        raise PointCloudFileError(f"{path}: LAZ chunk table at byte {table:,} lies outside the "
                                  f"points of a file of {size:,} bytes (truncated or corrupt "
                                  f"file)")
    area = table - start - 8  # the chunks' bytes
    fh.seek(table + 4)  # after its version
    count = struct.unpack("<I", fh.read(4))[0]
    if count > area:  # a chunk takes a byte at least (its first point is stored whole)
        raise PointCloudFileError(f"{path}: LAZ chunk table claims {count:,} chunks, more than "
                                  f"the {area:,} bytes of points before it hold (corrupt file)")
    try:
        import lazrs
    except ImportError:
        return  # laspy refuses to decompress without it
    try:
        fh.seek(start)
        chunks = lazrs.read_chunk_table(fh, lazrs.LazVlr(record))
    except RuntimeError as exc:  # lazrs.LazrsError
        raise corrupt(path, exc) from None
    if sum(nbytes for _, nbytes in chunks) > area:
        raise PointCloudFileError(f"{path}: LAZ chunks claim more than the {area:,} bytes of "
                                  f"points before the chunk table (corrupt file)")
    if chunk_size == _LAZ_VARIABLE:
        if sum(points for points, _ in chunks) != n:
            raise PointCloudFileError(f"{path}: LAZ chunks hold other than the header's {n:,} "
                                      f"points (corrupt file)")
    elif n and (chunk_size == 0 or chunk_size > max(n, _LAS_CHUNK)
                or len(chunks) != -(-n // chunk_size)):
        raise PointCloudFileError(f"{path}: {len(chunks):,} LAZ chunks of {chunk_size:,} points "
                                  f"do not hold the header's {n:,} points (corrupt file)")
    items = [struct.unpack_from("<HH", record, _LAZ_ITEMS + 6 * i)
             for i in range(struct.unpack_from("<H", record, _LAZ_ITEMS - 2)[0])
             if _LAZ_ITEMS + 6 * i + 6 <= len(record)]
    if compressor != _LAZ_LAYERED or any(k not in _LAZ_LAYERS and k != _LAZ_BYTES
                                         for k, _ in items):
        return
    raw = sum(size for _, size in items)  # the chunk's first point, whole
    layers = sum(size if kind == _LAZ_BYTES else _LAZ_LAYERS[kind] for kind, size in items)
    at = start + 8
    for i, (_, nbytes) in enumerate(chunks):  # a point count, then each layer's size
        fh.seek(at + raw + 4)
        sizes = fh.read(4 * layers)
        if (len(sizes) < 4 * layers
                or raw + 4 + len(sizes) + sum(struct.unpack(f"<{layers}I", sizes)) > nbytes):
            raise PointCloudFileError(f"{path}: the layers of LAZ chunk {i + 1:,} of "
                                      f"{len(chunks):,} claim more than its {nbytes:,} bytes "
                                      f"(corrupt file)")
        at += nbytes


def failures(laspy):
    """What laspy and lazrs raise on corrupt bytes: laspy's own errors, lazrs' (RuntimeError),
    struct and EOF errors of short records, and ZeroDivisionError from an extra-bytes
    description of zero elements."""
    return (laspy.LaspyException, RuntimeError, ValueError, EOFError, struct.error,
            ZeroDivisionError)


def read_records(reader, n):
    """Up to ``n`` raw point records from a laspy reader, read in growing pieces (fewer when
    the data ends first; lazrs raises instead); one of :func:`failures` on corrupt data."""
    size = reader.header.point_format.size
    chunks, got = [], 0
    while got < n:
        want = min(_LAS_CHUNK, max(_LAS_FIRST_BYTES // size, got, 1), n - got)
        chunk = reader.read_points(want).array
        if len(chunk) == 0:
            break
        chunks.append(chunk)
        got += len(chunk)
    return np.concatenate(chunks) if chunks else np.zeros(0, reader.header.point_format.dtype())


def corrupt(path, exc):
    """The error for one of :func:`failures`."""
    return PointCloudFileError(f"{path}: cannot read LAS/LAZ data (truncated or corrupt file): "
                               f"{' '.join(str(exc).split())}")


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
    size = stream_size(fh)
    check_header(path, fh, size)
    try:
        reader = laspy.LasReader(fh, closefd=False)
    except failures(laspy) as exc:
        raise corrupt(path, exc) from None
    header = reader.header
    n = header.point_count
    try:
        records = read_records(reader, n)
    except failures(laspy) as exc:
        raise corrupt(path, exc) from None
    if len(records) < n:
        raise PointCloudFileError(f"{path}: header claims {n:,} points but only "
                                  f"{len(records):,} could be read (truncated)")
    rec = laspy.ScaleAwarePointRecord(records, header.point_format, header.scales,
                                      header.offsets)
    points = np.column_stack([records[c] * s + o for c, s, o in
                              zip("XYZ", header.scales, header.offsets, strict=True)])
    values = {}
    for name in header.point_format.dimension_names:
        if name in ("X", "Y", "Z"):
            continue
        try:
            # A copy: fields must not be views into the records kept for writing back.
            values[name] = np.array(rec[name])
        except failures(laspy) as exc:  # a name the extra-bytes VLR lost: no such field
            raise PointCloudFileError(f"{path}: cannot read its dimension {name!r} (corrupt "
                                      f"extra-bytes VLR): {' '.join(str(exc).split())}") from None
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


#: The fewest steps of a new LAS file's scale across the points' mean spacing: a scale of a
#: hundredth of the spacing moves a point by at most 0.005 spacings, far below any noise a
#: denoiser keeps.
SPACING_STEPS = 100


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
                                  f"{scales.tolist()} and offset {offsets.tolist()} can hold "
                                  f"(points far from the rest, a stray return or a row at the "
                                  f"origin? or write another format, .ply or .npy)")
    return q.astype(np.int32)


def _scales_offsets(points, source):
    """The scale and offset of a LAS output of ``points``: the ``source``'s, or a new file's
    (the bounding-box centre, and per axis the smallest power of ten that keeps the extent
    inside int32)."""
    if source is not None:
        return np.asarray(source.header.scales), np.asarray(source.header.offsets)
    lo, hi = points.min(axis=0), points.max(axis=0)
    # 2**30 leaves a factor of two for rounding up to a power of ten; 1e-3 floors the
    # half-extent of flat or single-point clouds (scale 1e-12).
    return 10.0 ** np.ceil(np.log10(np.maximum((hi - lo) / 2, 1e-3) / 2**30)), (lo + hi) / 2


def _new_scales(path, points):
    """:func:`_scales_offsets` of a new file, refused where the scale would leave fewer than
    :data:`SPACING_STEPS` steps across the points' spacing."""
    scales, offsets = _scales_offsets(points, None)
    spacing = mean_spacing(points) if points.shape[0] > 1 else 0.0
    if spacing > 0.0 and (scales > spacing / SPACING_STEPS).any():
        extent = float((points.max(axis=0) - points.min(axis=0)).max())
        raise PointCloudFileError(
            f"{path}: a LAS file holds coordinates as 32-bit integers, and these points, "
            f"{extent:.3g} across, need a scale of {scales.max():.3g}: fewer than "
            f"{SPACING_STEPS} steps across their spacing of about {spacing:.3g}. Points far "
            f"from the rest (a stray return, a row at the origin) stretch the extent: remove "
            f"them, or write another format (.ply, .npy)")
    return scales, offsets


def stored(path, points, source):
    """``points`` as a LAS output holds them (:func:`payload`): rounded to its scale."""
    scales, offsets = (_scales_offsets(points, source) if source is not None
                       else _new_scales(path, points))
    return _quantise(path, points, scales, offsets) * scales + offsets


def _new_las(laspy, path, points):
    """LAS 1.4, point format 6, with :func:`_new_scales`."""
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales, header.offsets = _new_scales(path, points)
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
        If coordinates do not fit the int32 range, a new file's scale would leave fewer than
        :data:`SPACING_STEPS` steps across their spacing, a field is named ``X``, ``Y`` or
        ``Z``, a new name is longer than 32 bytes, or a value does not fit its dimension.
    ImportError
        If ``laspy`` is not installed, or ``.laz`` output lacks its lazrs backend.
    """
    laspy = _need_laspy(ext, "Writing")
    if source is None:
        las = _new_las(laspy, path, points)
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
