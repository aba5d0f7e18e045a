"""The readers under fuzz: small valid files of every format, mutated, and random bytes.

Every case must end within :data:`LIMIT` seconds, allocate at most a bounded multiple of the
file's size, write no file, warn nothing, and either raise the library's own exception (one
line naming the file) or return points that are what the file's bytes say (an independent
decoding of each format, :func:`what_the_bytes_say`). The default run tries a few hundred
cases; ``pytest -m slow`` tries more than ten thousand.
"""
import contextlib
import gzip
import io
import os
import re
import resource
import shutil
import signal
import struct
import sys
import tempfile
import time
import tracemalloc
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from pssd_fast import io as pio
from pssd_fast.io import PointCloudFileError

from .conftest import pssd

pytestmark = pytest.mark.skipif(not hasattr(signal, "setitimer"),
                                reason="the cases are timed with SIGALRM (POSIX only)")
plyfile = pytest.importorskip("plyfile")
laspy = pytest.importorskip("laspy")
zarr = pytest.importorskip("zarr")
numcodecs = pytest.importorskip("numcodecs")

#: Seconds a case may take: the files are at most a few kilobytes.
LIMIT = 1.0
#: Points of each valid file.
N = 12
#: Bytes a read may allocate (tracemalloc's peak): this much plus ``GROWTH`` times the file's
#: size (its decompressed size for gzip): a count from a header must not size an allocation.
SLACK = 8 << 20
GROWTH = 64
#: The most a case may raise the process's peak resident memory: what Rust and C code (lazrs,
#: the Zarr codecs) allocates is invisible to tracemalloc.
RSS_GROWTH = 512 << 20

FUZZ = dict(deadline=None, derandomize=True, database=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
slow = pytest.mark.slow


def depth(quick, long):
    """A fuzz test's number of examples: ``quick`` in the default suite, ``long`` among the
    slow tests."""
    return pytest.mark.parametrize("examples", [quick, pytest.param(long, marks=slow)],
                                   ids=["quick", "at_length"])


def fuzz(examples, check, **strategies):
    """``check`` on ``examples`` cases drawn from ``strategies`` (Hypothesis' ``given``)."""
    settings(max_examples=examples, **FUZZ)(given(**strategies)(check))()


# ---------------------------------------------------------------------------------------------
# Valid files


@dataclass(frozen=True)
class Seed:
    name: str
    suffix: str  # what the reader dispatches on: ".ply", ".xyz.gz"...
    data: bytes


def _cloud(seed=0):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(N, 3)).round(4)
    normals = rng.normal(size=(N, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, normals.round(4), rng


def _written(suffix, cloud, **kwargs):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"seed{suffix}"
        pio.write(path, cloud, **kwargs)
        return path.read_bytes()


def _ply(text, byte_order, faces=True, range_grid=False):
    points, normals, rng = _cloud(1)
    vertex = np.zeros(N, [("x", "f4"), ("y", "f4"), ("z", "f4"), ("nx", "f4"), ("ny", "f4"),
                          ("nz", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, c in enumerate("xyz"):
        vertex[c], vertex["n" + c] = points[:, i], normals[:, i]
    for c in ("red", "green", "blue"):
        vertex[c] = rng.integers(0, 256, N)
    elements = [plyfile.PlyElement.describe(vertex, "vertex")]
    if faces or range_grid:
        rows = N if range_grid else N - 2
        lists = np.empty(rows, [("vertex_indices", "O")])
        for i in range(rows):
            # A range grid has a row per scanner pixel; pixels without a return are empty.
            empty = range_grid and i % 3 == 1
            lists["vertex_indices"][i] = np.array([] if empty else [i, (i + 1) % N, (i + 2) % N],
                                                  np.int32)
        elements.append(plyfile.PlyElement.describe(
            lists, "range_grid" if range_grid else "face", val_types={"vertex_indices": "i4"}))
    out = io.BytesIO()
    plyfile.PlyData(elements, text=text, byte_order=byte_order, comments=["made by a test"],
                    obj_info=["num_cols 4"]).write(out)
    return out.getvalue()


def _text(suffix):
    points, normals, rng = _cloud(2)
    if suffix == ".xyz":
        fields = {"quality": rng.normal(size=N).round(3)}
        return _written(suffix, pio.PointCloud(points, normals, fields))
    if suffix == ".csv":
        fields = {c: rng.integers(0, 256, N).astype(np.uint8) for c in ("red", "green", "blue")}
        return _written(suffix, pio.PointCloud(points, None, fields))
    if suffix == ".pts":
        fields = {"intensity": rng.integers(-2048, 2048, N).astype(np.int32)}
        return _written(suffix, pio.PointCloud(points, None, fields))
    rows = "".join(f"{x} {y} {z}\n" for x, y, z in points)
    return f"# a scan, headerless\n{rows}".encode()


def _obj():
    points, normals, _ = _cloud(3)
    lines = ["# an OBJ file", "mtllib scan.mtl", "o scan"]
    lines += [f"v {x} {y} {z}" for x, y, z in points]
    lines += [f"vn {x} {y} {z}" for x, y, z in normals]
    lines += [f"f {i} {i + 1} {i + 2}" for i in range(1, N - 1)]
    return ("\n".join(lines) + "\n").encode()


def _npz():
    points, normals, rng = _cloud(4)
    out = io.BytesIO()
    np.savez_compressed(out, points=points, normals=normals, quality=rng.normal(size=N))
    return out.getvalue()


def _las(suffix, legacy=False):
    points, normals, rng = _cloud(5)
    if not legacy:
        cloud = pio.PointCloud(points * 100 + 1000, normals,
                               {"intensity": rng.integers(0, 2**16, N).astype(np.uint16)})
        return _written(suffix, cloud)
    header = laspy.LasHeader(version="1.2", point_format=3)
    header.scales = np.full(3, 0.001)
    header.offsets = np.array([5e5, 4e6, 300.0])
    header.vlrs.append(laspy.VLR("pssd_test", 42, "a VLR", b"vlr payload"))
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(N, header=header))
    las.X, las.Y, las.Z = rng.integers(-10**6, 10**6, (3, N))
    las.classification = rng.integers(0, 32, N)
    out = io.BytesIO()
    las.write(out)
    return out.getvalue()


def _npy(columns, dtype):
    points, normals, _ = _cloud(6)
    out = io.BytesIO()
    np.save(out, np.hstack([points, normals])[:, :columns].astype(dtype))
    return out.getvalue()


@cache
def seeds():
    """The valid files, by name; each reads back as a cloud of :data:`N` points."""
    found = [
        Seed("ply-ascii", ".ply", _ply(True, "=")),
        Seed("ply-binary-le", ".ply", _ply(False, "<")),
        Seed("ply-binary-be", ".ply", _ply(False, ">", faces=False)),
        Seed("ply-range-grid", ".ply", _ply(True, "=", faces=False, range_grid=True)),
        *(Seed(s.lstrip("."), s, _text(s)) for s in (".xyz", ".csv", ".pts", ".txt")),
        Seed("obj", ".obj", _obj()),
        Seed("npy", ".npy", _npy(3, np.float32)),
        Seed("npy6", ".npy", _npy(6, np.float64)),
        Seed("npz", ".npz", _npz()),
        Seed("las", ".las", _las(".las")),
        Seed("las12", ".las", _las(".las", legacy=True)),
        Seed("laz", ".laz", _las(".laz")),
    ]
    plain = {s.name: s for s in found}
    for name in ("ply-ascii", "xyz", "obj"):
        found.append(Seed(f"{name}.gz", plain[name].suffix + ".gz",
                          gzip.compress(plain[name].data, mtime=0)))
    return {s.name: s for s in found}


SEED_NAMES = ["ply-ascii", "ply-binary-le", "ply-binary-be", "ply-range-grid", "xyz", "csv", "pts",
              "txt", "obj", "npy", "npy6", "npz", "las", "las12", "laz", "ply-ascii.gz", "xyz.gz",
              "obj.gz"]
SUFFIXES = sorted(pio.formats())


def test_the_seeds_are_valid_files_of_n_points(tmp_path):
    assert sorted(seeds()) == sorted(SEED_NAMES)
    for seed in seeds().values():
        path = tmp_path / f"{seed.name}{seed.suffix}"
        path.write_bytes(seed.data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the range grid's, until the reader silences it
            points = pio.read(path).points
        assert len(points) == N, seed.name
        assert _matches(points, what_the_bytes_say(seed.suffix, seed.data)), seed.name


# ---------------------------------------------------------------------------------------------
# Mutations: each strategy draws (what was done, the new bytes)


def _kind(suffix):
    return suffix.removesuffix(".gz")


def header_end(suffix, data):
    """Where the body starts (the point data, or the first data line); the middle of a file
    whose header is already broken."""
    try:
        return min(_header_end(suffix, data), len(data))
    except struct.error:
        return len(data) // 2


def _header_end(suffix, data):
    kind = _kind(suffix)
    if suffix.endswith(".gz"):
        return 10
    if kind == ".ply":
        end = data.find(b"end_header")
        return data.find(b"\n", end) + 1 if end >= 0 else len(data) // 2
    if kind in (".las", ".laz"):
        return struct.unpack_from("<I", data, 96)[0]
    if kind == ".npy":
        return 10 + struct.unpack_from("<H", data, 8)[0]
    if kind == ".npz":
        return 30 + sum(struct.unpack_from("<HH", data, 26))
    first = re.search(rb"^(v |-?\d)", data, re.M)
    return first.start() if first else 0


def truncated(suffix, data):
    """``data`` cut in each length class: empty, a byte, inside the header, at its end, inside
    the body, a byte short."""
    n, head = len(data), header_end(suffix, data)
    classes = [
        st.sampled_from(sorted({0, 1, head - 1, head, head + 1, n - 1} - {-1, n})),
        st.integers(1, max(head - 1, 1)),  # inside the header
        st.integers(min(head, n - 1), n - 1),  # inside the body
    ]
    return st.one_of(classes).map(lambda k: (f"truncated to {k} of {n} bytes", data[:k]))


def _number(old):
    return st.sampled_from([0, 1, old - 1, old + 1, 2 * old, 2**31 - 1, 2**31, 2**32 - 1, 2**32,
                            2**63, 2**64, 10**12, -1])


def _replace_match(data, match, group, new):
    start, end = match.span(group)
    return data[:start] + new + data[end:]


@st.composite
def _regex_swap(draw, data, pattern, values, what):
    """One match of ``pattern``'s group 1 replaced by a drawn value."""
    matches = list(re.finditer(pattern, data, re.M))
    if not matches:
        return "unchanged", data
    match = draw(st.sampled_from(matches))
    old = match.group(1)
    new = draw(values(old))
    new = new if isinstance(new, bytes) else str(new).encode()
    return f"{what} {old!r} -> {new!r}", _replace_match(data, match, 1, new)


def _ply_counts(data):
    return _regex_swap(data, rb"^element \S+ (\d+)",
                       lambda old: _number(int(old)) | st.sampled_from([b"", b"1e3", b"x"]),
                       "element count")


PLY_TYPES = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8",
             "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64", "float16",
             "int64", "long", "list", "blah"]


def _ply_types(data):
    return _regex_swap(data, rb"^property (?:list )?(\w+)",
                       lambda old: st.sampled_from(PLY_TYPES), "property type")


# LAS header fields (offset, struct format): what a corrupt or lying header changes.
LAS_FIELDS = {"version minor": (25, "B"), "header size": (94, "<H"),
              "offset to points": (96, "<I"), "VLR count": (100, "<I"),
              "point format": (104, "B"), "record length": (105, "<H"),
              "legacy point count": (107, "<I"), "x scale": (131, "<d"),
              "x offset": (155, "<d"), "first EVLR": (235, "<Q"), "EVLR count": (243, "<I"),
              "point count": (247, "<Q")}


@st.composite
def _las_header(draw, data):
    name = draw(st.sampled_from(sorted(LAS_FIELDS)))
    at, fmt = LAS_FIELDS[name]
    if at + struct.calcsize(fmt) > len(data):
        return "unchanged", data
    old = struct.unpack_from(fmt, data, at)[0]
    if fmt == "<d":
        new = draw(st.sampled_from([0.0, -old, 1e-300, 1e300, float("nan"), float("inf")]))
    else:
        limit = 2 ** (8 * struct.calcsize(fmt)) - 1
        new = min(max(draw(_number(old) | st.integers(0, limit)), 0), limit)
    new_bytes = struct.pack(fmt, new)
    return f"LAS {name} {old} -> {new}", data[:at] + new_bytes + data[at + len(new_bytes):]


def _npy_rebuilt(data, header):
    """An .npy file with another header dictionary (length and padding recomputed)."""
    body = data[10 + struct.unpack_from("<H", data, 8)[0]:]
    text = header.rstrip(b" \n")
    pad = -(10 + len(text) + 1) % 64
    text += b" " * pad + b"\n"
    return data[:8] + struct.pack("<H", len(text)) + text + body


NPY_SHAPES = ["()", "(12,)", "(11, 3)", "(13, 3)", "(12, 4)", "(12, 3, 1)", "(-1, 3)",
              "(1000000000000, 3)", "(2**63, 3)", "(9223372036854775807, 3)", "(0, 3)", "'x'",
              "(12, 2)", "(6, 6)", "(24, 3)"]
NPY_DESCRS = ["'<f8'", "'>f8'", "'<f4'", "'<f2'", "'|u1'", "'<i8'", "'|b1'", "'<c16'", "'<U2'",
              "'|S3'", "'|O'", "'<M8[s]'", "[('x', '<f4')]", "'V12'", "'<f16'", "'bogus'"]


@st.composite
def _npy_header(draw, data):
    if not data.startswith(b"\x93NUMPY\x01\x00") or len(data) < 10:
        return "unchanged", data
    head = data[10:10 + struct.unpack_from("<H", data, 8)[0]]
    key, values = draw(st.sampled_from([(b"shape", NPY_SHAPES), (b"descr", NPY_DESCRS),
                                        (b"fortran_order", ["True", "1", "None"])]))
    match = re.search(rb"'" + key + rb"': (\([^)]*\)|'[^']*'|\w+)", head)
    if match is None:
        return "unchanged", data
    new = draw(st.sampled_from(values)).encode()
    return (f"npy {key.decode()} {match.group(1)!r} -> {new!r}",
            _npy_rebuilt(data, _replace_match(head, match, 1, new)))


@st.composite
def _npz_member(draw, data):
    """The ``points`` array of an .npz mutated as an .npy file, the archive rebuilt."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            members = {info.filename: zf.read(info) for info in zf.infolist()}
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError):
        return "unchanged", data
    if "points.npy" not in members:
        return "unchanged", data
    label, members["points.npy"] = draw(_mutation(".npy", members["points.npy"]))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, member in members.items():
            zf.writestr(name, member)
    return f"npz points.npy {label}", out.getvalue()


TOKENS = ["nan", "inf", "-0", "1e400", "0x10", "1_0", "\uff11", "", "abc", "1,5", "1e", "--1",
          "\x00", "300", "-1", "4294967296", "1.5", "1e-400", "+1", ".", "#", "//", ";", "\t"]


@st.composite
def _lines(draw, data):
    """A line deleted, doubled or moved, or one of its tokens replaced."""
    lines = data.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    op = draw(st.sampled_from(["delete", "double", "move", "token"]))
    if op == "delete":
        del lines[i]
    elif op == "double":
        lines.insert(i, lines[i])
    elif op == "move":
        lines.insert(draw(st.integers(0, len(lines) - 1)), lines.pop(i))
    else:
        tokens = re.split(rb"([ ,;\t]+)", lines[i])
        j = draw(st.integers(0, len(tokens) - 1))
        tokens[j] = draw(st.sampled_from(TOKENS)).encode("utf-8")
        lines[i] = b"".join(tokens)
    return f"line {i + 1} {op}", b"\n".join(lines)


@st.composite
def _bytes_changed(draw, data):
    """Random bytes overwritten, inserted or deleted, or a slice doubled, a bit flipped."""
    n = len(data)
    at = draw(st.integers(0, max(n - 1, 0)))
    op = draw(st.sampled_from(["overwrite", "insert", "delete", "double", "flip"]))
    if op == "flip":
        bit = draw(st.integers(0, 7))
        return (f"bit {bit} of byte {at} flipped",
                data[:at] + bytes([data[at] ^ (1 << bit)]) + data[at + 1:] if n else data)
    size = draw(st.integers(1, 16))
    if op == "overwrite":
        new = draw(st.binary(min_size=size, max_size=size))
        return f"{size} bytes at {at} overwritten", data[:at] + new + data[at + size:]
    if op == "insert":
        new = draw(st.binary(min_size=1, max_size=size))
        return f"{len(new)} bytes inserted at {at}", data[:at] + new + data[at:]
    if op == "delete":
        return f"{size} bytes deleted at {at}", data[:at] + data[at + size:]
    return f"{size} bytes at {at} doubled", data[:at + size] + data[at:]


def _other_format(suffix):
    others = [s for s in seeds().values() if s.suffix != suffix]
    return st.sampled_from(others).map(lambda s: (f"the bytes of {s.name}", s.data))


def _mutation(suffix, data):
    kind = _kind(suffix)
    options = [truncated(suffix, data), _bytes_changed(data), _other_format(suffix)]
    if suffix.endswith(".gz"):
        return st.one_of(options)
    if kind == ".ply":
        options += [_ply_counts(data), _ply_types(data)]
    elif kind in (".las", ".laz"):
        options += [_las_header(data)] * 2
    elif kind == ".npy":
        options += [_npy_header(data)] * 2
    elif kind == ".npz":
        options += [_npz_member(data)] * 2
    else:  # text and OBJ
        options += [_lines(data)] * 2
        if kind == ".pts":
            options.append(_regex_swap(data, rb"\A(\d+)", lambda old: _number(int(old)),
                                       "point count"))
    return st.one_of(options)


@st.composite
def mutated(draw, name):
    """A mutated copy of the seed ``name``: (suffix, what was done, bytes). A gzipped seed has
    either its compressed bytes or its content mutated (then compressed again); a second
    mutation may follow the first."""
    seed = seeds()[name]
    data, done = seed.data, []
    if seed.suffix.endswith(".gz") and draw(st.booleans()):
        label, inner = draw(_mutation(_kind(seed.suffix), gzip.decompress(data)))
        data, done = gzip.compress(inner, mtime=0), [f"content {label}"]
    else:
        label, data = draw(_mutation(seed.suffix, data))
        done.append(label)
        if len(data) >= 16 and draw(st.integers(0, 3)) == 0:
            label, data = draw(_mutation(seed.suffix, data))
            done.append(label)
    return seed.suffix, "; ".join(done), data


def random_file(suffix):
    """Random bytes, alone or after the magic of the suffix's format."""
    magic = {".ply": [b"ply\nformat ascii 1.0\n", b"ply\nformat binary_little_endian 1.0\n"
                      b"element vertex 3\nproperty float x\nproperty float y\n"
                      b"property float z\nend_header\n"],
             ".las": [b"LASF"], ".laz": [b"LASF"], ".npy": [b"\x93NUMPY\x01\x00"],
             ".npz": [b"PK\x03\x04"]}.get(_kind(suffix), [b""])
    return st.tuples(st.sampled_from([b"", *magic]), st.binary(max_size=600)).map(
        lambda parts: (suffix, f"random bytes after {parts[0][:12]!r}", b"".join(parts)))


# ---------------------------------------------------------------------------------------------
# What the bytes say: an independent decoding of each format, or None where it cannot say


def what_the_bytes_say(suffix, data):
    """The (n, 3) float64 points a file's bytes hold, decoded here without pssd_fast, or None
    when they hold no clear answer (the reader must then refuse the file or agree with this
    function's caller on nothing more than the contract)."""
    kind = _kind(suffix)
    if suffix.endswith(".gz"):
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error):
            return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return {".ply": _ply_points, ".las": _las_points, ".laz": _las_points,
                    ".npy": _npy_points, ".npz": _npz_points, ".obj": _obj_points}.get(
                kind, _text_points)(data)
    except Exception:  # anything this decoder cannot read has no clear answer
        return None


PLY_CODES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
             "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
             "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4",
             "float64": "f8"}


def _ply_points(data):
    """Vertices as the PLY specification lays them out; only a first 'vertex' element of
    scalar properties in a header with LF line ends."""
    end = data.index(b"\nend_header\n") + len(b"\nend_header\n")
    lines = data[:end].decode("ascii").split("\n")[:-1]
    assert lines[0] == "ply"
    fmt, elements = None, []
    for line in lines[1:]:
        tokens = line.split()
        if tokens[0] == "format":
            fmt = tokens[1]
        elif tokens[0] == "element":
            elements.append((tokens[1], int(tokens[2]), []))
        elif tokens[0] == "property":
            elements[-1][2].append((tokens[-1], PLY_CODES.get(tokens[1]), len(tokens)))
    name, count, props = elements[0]
    assert name == "vertex" and 0 < count <= len(data)
    assert all(code is not None and length == 3 for _, code, length in props)
    props = [(p, code) for p, code, _ in props]
    body = data[end:]
    if fmt == "ascii":
        rows = re.split(r"\r\n|\r|\n", body.decode("ascii"))[:count]
        table = {p: [np.dtype(code).type(row.split()[i]) for row in rows]
                 for i, (p, code) in enumerate(props)}
    else:
        order = {"binary_little_endian": "<", "binary_big_endian": ">"}[fmt]
        table = np.frombuffer(body, [(p, order + code) for p, code in props], count)
    return np.column_stack([np.asarray(table[c], np.float64) for c in "xyz"])


def _las_points(data):
    las = laspy.read(io.BytesIO(data))
    return np.column_stack([las.x, las.y, las.z]).astype(np.float64)


def _npy_points(data):
    arr = np.load(io.BytesIO(data), allow_pickle=False)
    assert arr.ndim == 2 and arr.shape[1] in (3, 6)
    return arr[:, :3].astype(np.float64)


def _npz_points(data):
    """The archive's points.npy (a zip may start with other bytes: np.load would refuse it)."""
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        member = io.BytesIO(zf.read("points.npy"))
    return np.asarray(np.lib.format.read_array(member, allow_pickle=False), np.float64)


def _obj_points(data):
    rows = []
    for line in data.decode("utf-8", "surrogateescape").split("\n"):
        if line.lstrip().startswith(("v ", "v\t")):  # a keyword, then white space
            rows.append([float(t) for t in line.split("#", 1)[0].split()[1:4]])
    return np.array(rows, np.float64).reshape(-1, 3)


def _text_points(data):
    """Every line of at least three numbers; the reader may take x y z from any columns."""
    rows = []
    for line in data.decode("utf-8", "surrogateescape").split("\n"):
        content = line.split("#", 1)[0].strip()
        if content.startswith("//"):
            continue
        sep = next((s for s in ";," if s in content), None)
        tokens = [t.strip() for t in content.split(sep)] if sep else content.split()
        try:
            rows.append([float(t) for t in tokens])
        except ValueError:
            continue
        if len(rows[-1]) < 3:
            rows.pop()
    return np.array(rows, np.float64) if rows else None


def _matches(points, table):
    """Whether each column of ``points`` is a column of ``table`` (the same rows)."""
    if table.ndim != 2 or len(table) != len(points):
        return False
    if table.shape[1] == 3:
        return np.array_equal(points, table)
    return all(any(np.array_equal(col, other) for other in table.T) for col in points.T)


# ---------------------------------------------------------------------------------------------
# Running one case


@pytest.fixture(scope="module")
def traced():
    """Allocations traced across the tests using it, each case measuring its own peak:
    stopping tracemalloc while zarr's decoding threads allocate crashes CPython 3.11 (other
    cases start and stop it themselves, which costs less than tracing all along)."""
    tracemalloc.start()
    yield
    tracemalloc.stop()


class CaseTimeout(BaseException):
    """Raised by the timer: a BaseException, so that no reader's ``except Exception`` eats it."""


def _peak_rss():
    """The process's peak resident memory, in bytes (getrusage gives KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin"
                                                                  else 1024)


@contextlib.contextmanager
def bounded(size, slack=SLACK):
    """Time and memory limits around one case, and no warnings; yields a dict that gets the
    seconds and the peak traced bytes."""
    usage = {}

    def expire(signum, frame):
        raise CaseTimeout(f"still running after {2 * LIMIT} s")

    # The timer stops a hang (at twice the limit, so that the clock, not the timer, judges a
    # case near it); the limit itself is checked on the clock below.
    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, 2 * LIMIT)
    tracing = tracemalloc.is_tracing()  # across the test: see traced()
    if not tracing:
        tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    rss = _peak_rss()
    started = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield usage
    except CaseTimeout as exc:  # a failure Hypothesis reports and shrinks, from here on
        raise AssertionError(str(exc)) from exc
    finally:
        usage["seconds"] = time.perf_counter() - started
        usage["peak"] = tracemalloc.get_traced_memory()[1] - base
        if not tracing:
            tracemalloc.stop()
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert usage["seconds"] < LIMIT, f"took {usage['seconds']:.2f} s"
    assert usage["peak"] <= slack + GROWTH * size, f"allocated {usage['peak']:,} bytes"
    assert _peak_rss() - rss <= RSS_GROWTH, f"resident memory grew by {_peak_rss() - rss:,} bytes"
    noise = [str(w.message) for w in caught if not issubclass(w.category, pio.PointCloudWarning)]
    assert not noise, f"warned: {noise}"


def _size(suffix, data):
    if suffix.endswith(".gz"):
        with contextlib.suppress(Exception):
            return max(len(data), len(gzip.decompress(data)))
    return len(data)


def check_message(exc, path):
    message = str(exc)
    assert "\n" not in message, message
    assert str(path) in message and len(message) > len(str(path)) + 10, message
    message.encode("utf-8")  # printable as the CLI prints it


def check_read(folder, suffix, data):
    """Read ``data`` as a file of ``suffix``: refused with PointCloudFileError, or read as
    the bytes say. Returns the error, or None for a read."""
    path = folder / f"case{suffix}"
    path.write_bytes(data)
    error = None
    with bounded(_size(suffix, data)):
        try:
            cloud = pio.read(path)
        except PointCloudFileError as exc:
            error = exc
    assert sorted(os.listdir(folder)) == [path.name], "the read wrote a file"
    if error is not None:
        check_message(error, path)
        return error
    n = len(cloud)
    assert n > 0 and cloud.points.shape == (n, 3) and cloud.points.dtype == np.float64
    assert np.isfinite(cloud.points).all()
    assert cloud.normals is None or (cloud.normals.shape == (n, 3)
                                     and cloud.normals.dtype == np.float64)
    assert all(values.shape == (n,) for values in cloud.fields.values())
    expected = what_the_bytes_say(suffix, data)
    assert expected is not None and _matches(cloud.points, expected), \
        f"read {n} points that are not what the bytes say: {cloud.points[:3]} vs {expected}"
    return None


@contextlib.contextmanager
def case_folder():
    folder = Path(tempfile.mkdtemp(prefix="pssd_fuzz_"))
    try:
        yield folder
    finally:
        shutil.rmtree(folder)


# ---------------------------------------------------------------------------------------------
# The fuzz tests


def _read_case(case):
    suffix, _, data = case
    with case_folder() as folder:
        check_read(folder, suffix, data)


@pytest.mark.parametrize("name", SEED_NAMES)
@depth(18, 600)
def test_mutated_files_are_read_as_they_are_or_refused(name, examples):
    def case(data):
        _read_case(data.draw(mutated(name), label="case"))
    fuzz(examples, case, data=st.data())


@pytest.mark.parametrize("suffix", SUFFIXES)
@depth(6, 150)
def test_random_bytes_with_each_suffix(suffix, examples):
    def case(data):
        _read_case(data.draw(random_file(suffix), label="case"))
    fuzz(examples, case, data=st.data())


# ---------------------------------------------------------------------------------------------
# The command line: a refused file leaves one line on stderr and no file behind


def _refusing(name):
    """Mutations of the seed ``name`` that leave most files unreadable: truncations and lying
    headers (or lines)."""
    seed = seeds()[name]
    kind = _kind(seed.suffix)
    options = [truncated(seed.suffix, seed.data)]
    options += {".ply": [_ply_counts(seed.data)], ".las": [_las_header(seed.data)],
                ".laz": [_las_header(seed.data)], ".npy": [_npy_header(seed.data)],
                ".npz": [_npz_member(seed.data)]}.get(kind, [_lines(seed.data)])
    return st.one_of(options).map(lambda case: (seed.suffix, *case))


CLI_SEEDS = ["ply-binary-le", "ply-ascii.gz", "csv", "obj", "npy", "npz", "las", "laz"]


def _cli_case(case, tiled):
    suffix, _, data = case
    with case_folder() as folder:
        bad, out = folder / f"bad{suffix}", folder / f"out{suffix}"
        bad.write_bytes(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                pio.read(bad)
        except PointCloudFileError:
            pass
        else:
            reject()  # a readable file would be denoised: not what this test is for
        # --tile-points takes .npy and LAS/LAZ files out of core, through other readers.
        extra = ["--tile-points", "1000"] if tiled else []
        status, stdout, stderr = pssd("denoise", bad, out, *extra)
        assert status == 1, (status, stdout, stderr)
        lines = stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("pssd: error: "), stderr
        assert str(bad) in lines[0], stderr
        assert sorted(os.listdir(folder)) == [bad.name], "a file was left behind"


@pytest.mark.parametrize("name", CLI_SEEDS)
@depth(4, 60)
def test_cli_refuses_a_broken_file_in_one_line_leaving_no_file(name, examples):
    def case(data, tiled):
        _cli_case(data.draw(_refusing(name), label="case"), tiled)
    fuzz(examples, case, data=st.data(), tiled=st.booleans())


# ---------------------------------------------------------------------------------------------
# The readers of tiled runs (pssd_fast.tiled.ondisk): .npy, LAS/LAZ and Zarr by chunks


def zarr_store(version, compressor):
    """A Zarr store of the points of :func:`_cloud` as {file: bytes}, in chunks of 5 rows: a
    v3 array of float64, or a v2 group holding float32 ``points``."""
    points = _cloud(7)[0]
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder) / "store.zarr"
        if version == 3:
            zarr.create_array(root, shape=(N, 3), dtype="f8", chunks=(5, 3),
                              compressors=compressor)[:] = points
        else:
            group = zarr.open_group(root, mode="w", zarr_format=2)
            group.create_array("points", shape=(N, 3), dtype="f4", chunks=(5, 3),
                               compressors=compressor)[:] = points
        return {str(f.relative_to(root)): f.read_bytes()
                for f in sorted(root.rglob("*")) if f.is_file()}


@cache
def zarr_seeds():
    """The Zarr stores fuzzed, compressed with codecs that check what they decode (gzip,
    zlib): the default ones, zstd (v3) and blosc (v2), trust a corrupt chunk's header,
    allocating the size it claims, and numcodecs' blosc reads past a truncated chunk (a known
    bug there), which no reader built on zarr can tell from data."""
    return {"v3.zarr": zarr_store(3, zarr.codecs.GzipCodec(level=1)),
            "v2.zarr": zarr_store(2, numcodecs.Zlib(level=1))}


@st.composite
def mutated_store(draw, name):
    """A Zarr store with one file mutated (its bytes, or a number of its JSON) or removed."""
    files = dict(zarr_seeds()[name])
    target = draw(st.sampled_from(sorted(files)))
    data = files[target]
    op = draw(st.sampled_from(["bytes", "number", "truncate", "remove"]))
    if op == "remove":
        del files[target]
        return f"{target} removed", files
    if op == "number":
        # Small numbers only: a Zarr array may lack chunks (they read as its fill value), so a
        # shape of 10**12 rows is a sparse array, read as slowly as that many rows are.
        label, files[target] = draw(_regex_swap(
            data, rb"(\d+)", lambda old: st.sampled_from([0, 1, int(old) - 1, int(old) + 1,
                                                           2 * int(old), -1]), "number"))
    elif op == "truncate":
        label, files[target] = draw(truncated(".json", data))
    else:
        label, files[target] = draw(_bytes_changed(data))
    return f"{target}: {label}", files


def _zarr_points(path):
    from pssd_fast.tiled import ondisk

    found = zarr.open(str(path), mode="r")
    found = found if hasattr(found, "shape") else found["points"]
    return np.asarray(found[0:ondisk.CHUNK_POINTS], np.float64)


def _tiled_readers():
    """The tiled runs' reader of each suffix."""
    from pssd_fast.tiled import ondisk

    return {".npy": ondisk.NpyFile, ".las": ondisk.LasFile, ".laz": ondisk.LasFile,
            ".zarr": ondisk.ZarrFile}


def check_tiled(folder, suffix, content):
    """Open ``content`` (bytes, or a Zarr store's files) as a tiled run does and read its first
    chunk: refused with a ValueError or TypeError naming the file, or read as it is. Returns
    the error, or None for a read."""
    from pssd_fast.tiled import ondisk

    # The tiled readers read windows of ondisk.CHUNK_POINTS rows (24 MiB of float64 points,
    # and their records or decoded chunks on the way).
    slack = SLACK + 4 * ondisk.CHUNK_POINTS * 3 * 8
    path = folder / f"case{suffix}"
    if isinstance(content, dict):
        for name, data in content.items():
            (path / name).parent.mkdir(parents=True, exist_ok=True)
            (path / name).write_bytes(data)
        size = sum(map(len, content.values()))
    else:
        path.write_bytes(content)
        size = len(content)
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    error = None
    with bounded(size, slack):
        try:
            array = _tiled_readers()[suffix](path)
            # The first of the chunks ondisk.chunks reads (none of an empty file).
            got = array[0:ondisk.CHUNK_POINTS] if array.shape[0] else np.empty((0, 3))
        except (ValueError, TypeError) as exc:
            error = exc
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before
    if error is not None:
        check_message(error, path)
        return error
    if suffix == ".zarr":
        expected = _zarr_points(path)
    else:
        expected = what_the_bytes_say(suffix, content)
    assert expected is not None and np.array_equal(np.asarray(got, np.float64), expected,
                                                   equal_nan=True)
    return None


TILED_SEEDS = ["npy", "las", "laz", "v3.zarr", "v2.zarr"]


def _tiled_case(name, data):
    if name.endswith(".zarr"):
        suffix, content = ".zarr", data.draw(mutated_store(name), label="case")[1]
    else:
        suffix, _, content = data.draw(mutated(name), label="case")
    with case_folder() as folder:
        check_tiled(folder, suffix, content)


@pytest.mark.usefixtures("traced")
@pytest.mark.parametrize("name", TILED_SEEDS)
@depth(8, 160)
def test_tiled_readers_read_a_broken_file_as_it_is_or_name_it(name, examples):
    def case(data):
        _tiled_case(name, data)
    fuzz(examples, case, data=st.data())


# ---------------------------------------------------------------------------------------------
# What the fuzzer found: each input as it failed before its fix, as an explicit example


def _put(at, new):
    return lambda data: data[:at] + new + data[at + len(new):]


def _sub(old, new):
    return lambda data: data.replace(old, new, 1)


def _las_field(name, value):
    at, fmt = LAS_FIELDS[name]
    return _put(at, struct.pack(fmt, value))


def _chunk_count(value):
    """The chunk count of a LAZ file's chunk table (its offset starts the points)."""
    def edit(data):
        table = struct.unpack_from("<q", data, struct.unpack_from("<I", data, 96)[0])[0]
        return _put(table + 4, struct.pack("<I", value))(data)
    return edit


def _laszip_field(at, value):
    """A 32-bit field of a LAZ file's laszip VLR record (the chunk size is at 12)."""
    def edit(data):
        record = data.find(b"laszip encoded") - 2 + 54
        return _put(record + at, struct.pack("<I", value))(data)
    return edit


def _layer_size(value):
    """The size of the first layer of a LAZ file's first chunk (after its first point, 42
    bytes in the seed, and its point count)."""
    def edit(data):
        return _put(struct.unpack_from("<I", data, 96)[0] + 8 + 42 + 4,
                    struct.pack("<I", value))(data)
    return edit


def _zip_member(flags=0, method=None):
    """The first member of an archive with ``flags`` set (1: encrypted) or another compression
    ``method``, in its local header and in the central directory (fields 2 bytes later)."""
    def edit(data):
        out = bytearray(data)
        for base in (0, data.find(b"PK\x01\x02") + 2):
            out[base + 6] |= flags
            if method is not None:
                out[base + 8:base + 10] = struct.pack("<H", method)
        return bytes(out)
    return edit


def _npy_shape(shape):
    return lambda data: _npy_rebuilt(data, data[10:10 + struct.unpack_from("<H", data, 8)[0]]
                                     .replace(b"(12, 3)", shape))


def _unchanged(data):
    return data


# name: (seed, edit, what the error says, or None for a read)
FOUND = {
    # plyfile: OverflowError for an ASCII value beyond its integer type (once a type swap).
    "ply value beyond its type": ("ply-ascii", _sub(b"property uchar red", b"property char red"),
                                  "does not fit the type of its PLY property"),
    "ply list length beyond its type": ("ply-ascii", _sub(b"\n3 0 1 2\n", b"\n300 0 1 2\n"),
                                        "does not fit the type of its PLY property"),
    # plyfile: a bare ValueError for names given twice.
    "ply element named twice": ("ply-ascii", _sub(b"element face", b"element vertex"),
                                "bad PLY header: two elements with same name"),
    "ply property named twice": ("ply-ascii", _sub(b"float y", b"float x"),
                                 "bad PLY header: two properties with same name"),
    # plyfile's text wrapper closed the file when collected, with a ResourceWarning.
    "ply ascii read": ("ply-ascii", _unchanged, None),
    # numpy warned "loadtxt: input contained no data" for each empty list.
    "ply range grid": ("ply-range-grid", _unchanged, None),
    # A signalling NaN made numpy warn "invalid value encountered in cast".
    "ply signalling nan": ("ply-binary-be", _sub(b"property float x", b"property short x"),
                           "have NaN or Inf coordinates"),
    # numpy: a bare ValueError from reading -3 elements.
    "npy negative shape": ("npy", _npy_shape(b"(-1, 3)"), r"shape \(-1, 3\), with a negative"),
    # numpy: tokenize.TokenError from the header of a Python 2 .npy file.
    "npy unterminated header": ("npy", lambda d: d[:11] + d[3:], "not a valid .npy array"),
    # Python: SyntaxWarning "invalid escape sequence" from the header literal.
    "npy backslash in header": ("npy6", _put(15, b"\x0e\xb2+\\Zm\x15'\xd3\xe4T\x04J\xb0-"),
                                "not a valid .npy array"),
    # zipfile: zlib.error, OSError, NotImplementedError, RuntimeError.
    "npz corrupt deflate": ("npz", _put(229, b"\xff" * 16), "not a readable .npz"),
    "npz bad offsets": ("npz", lambda d: d[:2] + d[3:], "not a readable .npz"),
    "npz unknown compression": ("npz", _zip_member(method=99), "not a readable .npz"),
    "npz encrypted": ("npz", _zip_member(flags=1), "not a readable .npz"),
    "npz bad bzip2": ("npz", _zip_member(method=12), "not a readable .npz"),
    # laspy: 2 GiB allocated from the offset to the points.
    "las offset to points": ("las12", _las_field("offset to points", 2**31 - 1),
                             "does not fit the file's 700 bytes"),
    # laspy: a loop over 4 billion VLRs (the case ran out of time).
    "las VLR count": ("las", _las_field("VLR count", 2**32 - 1), "4,294,967,295 VLRs"),
    # laspy: MemoryError reading an EVLR whose length is garbage.
    "las EVLR count": ("las", _las_field("EVLR count", 1), "1 EVLRs from byte 0"),
    # laspy: struct.error reading the fields of a LAS 1.255 header.
    "las version": ("las12", _las_field("version minor", 255), "LAS version 1.255"),
    # laspy: a bare ValueError for an extra-bytes dimension whose name lost its first byte.
    "las extra bytes name": ("las", _put(817, b"\0"), "cannot read its dimension ''"),
    # laspy: ZeroDivisionError from an extra-bytes description of zero elements.
    "las extra bytes": ("las", lambda d: d[:747] + d[737:], "cannot read LAS/LAZ data"),
    # lazrs: a chunk table of 3.2 billion entries (51.8 GB) aborted the process.
    "laz chunk count": ("laz", _chunk_count(3_238_000_000), "3,238,000,000 chunks"),
    # lazrs: chunks of 4,294,967,294 points (180 GB) aborted the process.
    "laz chunk size": ("laz", _laszip_field(12, 2**32 - 2), "do not hold the header's 12"),
    # lazrs: a Rust panic ("capacity overflow"), a BaseException, for chunks of 1 point.
    "laz chunk size 1": ("laz", _laszip_field(12, 1), "do not hold the header's 12"),
    # lazrs: 4 GB allocated (and 5 s spent) for a layer of a chunk claiming 4 GB.
    "laz layer size": ("laz", _layer_size(4_000_000_000), "layers of LAZ chunk 1 of 1"),
    # One piece of 2**20 points (44 MB) was allocated for a count the file cannot hold.
    "laz point count": ("laz", _las_field("point count", 10**12),
                        "do not hold the header's 1,000,000,000,000 points"),
}


@pytest.mark.parametrize("name", FOUND)
def test_what_the_fuzzer_found(name):
    seed, edit, match = FOUND[name]
    suffix = seeds()[seed].suffix
    with case_folder() as folder:
        error = check_read(folder, suffix, edit(seeds()[seed].data))
    if match is None:
        assert error is None
    else:
        assert error is not None and re.search(match, str(error)), error


# name: (suffix, content, what the error says)
FOUND_TILED = {
    # numpy: "the magic string is not correct", naming no file.
    "npy of another format": (".npy", lambda: seeds()["ply-binary-be"].data,
                              "not a valid .npy array"),
    # laspy: struct.error, naming no file.
    "las version": (".las", lambda: _las_field("version minor", 255)(seeds()["las12"].data),
                    "LAS version 1.255"),
    # laspy: after a seek, a 13th point of zeros from a LAZ file of 12 points.
    "laz point count": (".laz", lambda: _las_field("point count", 13)(seeds()["laz"].data),
                        "cannot read LAS/LAZ data"),
    # zarr: ZeroDivisionError from a chunk shape of 0.
    "zarr chunk shape 0": (".zarr", lambda: _zarr_edit(
        zarr_seeds()["v3.zarr"], "zarr.json", _sub(b"5,", b"0,")), "ZeroDivisionError"),
    # numcodecs: RuntimeError from a corrupt zstd chunk (Zarr v3's default codec).
    "zarr corrupt zstd chunk": (".zarr", lambda: _zarr_edit(
        zarr_store(3, zarr.codecs.ZstdCodec()), "c/0/0", lambda d: b"\0" * 8),
        "cannot read rows 0 to .* RuntimeError"),
    # numcodecs: MemoryError from a zstd chunk whose frame claims a terabyte.
    "zarr zstd chunk claiming a terabyte": (".zarr", lambda: _zarr_edit(
        zarr_store(3, zarr.codecs.ZstdCodec()), "c/0/0",
        lambda d: d[:4] + b"\xe0" + (2**40).to_bytes(8, "little") + d[6:]), "MemoryError"),
    # numcodecs: SystemError from a blosc chunk (Zarr v2's default) of negative size.
    "zarr blosc chunk of negative size": (".zarr", lambda: _zarr_edit(
        zarr_store(2, numcodecs.Blosc()), "points/0.0", _put(4, b"\xff" * 4)), "SystemError"),
}


def _zarr_edit(files, name, edit):
    return {**files, name: edit(files[name])}


@pytest.mark.usefixtures("traced")
@pytest.mark.parametrize("name", FOUND_TILED)
def test_what_the_fuzzer_found_in_tiled_readers(name):
    suffix, content, match = FOUND_TILED[name]
    with case_folder() as folder:
        error = check_tiled(folder, suffix, content())
    assert error is not None and re.search(match, str(error)), error


@pytest.mark.parametrize("compress", [False, True])
def test_tiled_las_reader_gives_the_rows_asked_in_any_order(tmp_path, compress):
    # Rows read on from the previous call, from row 0 afresh, or elsewhere (a seek).
    las = laspy.LasData(laspy.LasHeader(version="1.4", point_format=6))
    las.x, las.y, las.z = np.random.default_rng(8).uniform(0, 100, (3, 100))
    path = tmp_path / ("a.laz" if compress else "a.las")
    las.write(path, do_compress=compress)
    truth = np.column_stack([las.x, las.y, las.z])
    from pssd_fast.tiled import ondisk

    array = ondisk.LasFile(path)
    for start, stop in [(0, 30), (30, 70), (70, 100), (55, 95), (0, 100), (90, 100)]:
        assert np.array_equal(array[start:stop], truth[start:stop]), (start, stop)
    array.close()
