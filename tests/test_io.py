"""pssd_fast.io: round trips that keep every attribute, and one test per refused file."""
import contextlib
import dataclasses
import gzip
import struct
import sys
import tracemalloc
import warnings

import numpy as np
import pytest

from pssd_fast import io as pio
from pssd_fast.io import PointCloud, PointCloudFileError, PointCloudFileNotFoundError

from .conftest import laspy, needs_laspy, needs_plyfile, plyfile
HAVE_LAZRS = laspy is not None and laspy.LazBackend.LazrsParallel.is_available()
LAS_EXTS = [".las", pytest.param(".laz", marks=pytest.mark.skipif(not HAVE_LAZRS,
                                                                    reason="lazrs is missing"))]
N = 40
PLY_MODES = {"ascii": (True, "="), "binary_le": (False, "<"), "binary_be": (False, ">")}


def make_ply(path, mode="binary_le", n=N, seed=0):
    """A PLY with normals, colours, a float scalar, a face element, comments and obj_info."""
    rng = np.random.default_rng(seed)
    vertex = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("nx", "f4"),
                                ("ny", "f4"), ("nz", "f4"), ("red", "u1"), ("green", "u1"),
                                ("blue", "u1"), ("quality", "f4")])
    for name in ("x", "y", "z", "nx", "ny", "nz", "quality"):
        vertex[name] = rng.normal(size=n)
    for name in ("red", "green", "blue"):
        vertex[name] = rng.integers(0, 256, n)
    face = np.empty(n - 2, dtype=[("vertex_indices", "O")])
    for i in range(n - 2):
        face["vertex_indices"][i] = np.array([i, i + 1, i + 2], dtype=np.int32)
    text, byte_order = PLY_MODES[mode]
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex"),
                     plyfile.PlyElement.describe(face, "face",
                                                 val_types={"vertex_indices": "i4"})],
                    text=text, byte_order=byte_order, comments=["scanned by test"],
                    obj_info=["unit m"]).write(str(path))
    return vertex, face


def make_las(path, n=N, scale=0.001, offsets=(500000.0, 4000000.0, 300.0), point_format=3,
             seed=0, span=10**6):
    """A LAS 1.4 file with intensity, classification, returns, gps_time, RGB, a VLR and EVLR."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(version="1.4", point_format=point_format)
    header.scales = np.full(3, scale)
    header.offsets = np.array(offsets)
    header.vlrs.append(laspy.VLR("pssd_test", 42, "a VLR", b"vlr payload"))
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(n, header=header))
    las.X, las.Y, las.Z = rng.integers(-span, span, (3, n))
    las.intensity = rng.integers(0, 2**16, n)
    las.classification = rng.integers(0, 32, n)
    las.return_number = rng.integers(1, 6, n)
    las.number_of_returns = rng.integers(1, 6, n)
    las.gps_time = rng.uniform(0, 1e6, n)
    for name in ("red", "green", "blue"):
        las[name] = rng.integers(0, 2**16, n)
    from laspy.vlrs.vlrlist import VLRList

    las.evlrs = VLRList([laspy.VLR("pssd_test", 43, "an EVLR", b"evlr payload")])
    las.write(str(path))
    return laspy.read(str(path))


def test_formats_lists_every_extension():
    plain = {".ply", ".xyz", ".pts", ".txt", ".csv", ".obj", ".npy", ".npz", ".las", ".laz"}
    gzipped = {".ply.gz", ".xyz.gz", ".pts.gz", ".txt.gz", ".csv.gz", ".obj.gz"}
    assert pio.formats() == tuple(sorted(plain | gzipped))


# ---------------------------------------------------------------------------------------------
# PLY


@needs_plyfile
@pytest.mark.parametrize("mode", PLY_MODES)
def test_ply_read_gives_points_normals_and_typed_fields(tmp_path, mode):
    vertex, _ = make_ply(tmp_path / "a.ply", mode)
    cloud = pio.read(tmp_path / "a.ply")
    assert cloud.format == "ply"
    assert cloud.points.dtype == np.float64
    np.testing.assert_array_equal(cloud.points, np.column_stack([vertex[c] for c in "xyz"]))
    np.testing.assert_array_equal(cloud.normals,
                                  np.column_stack([vertex[c] for c in ("nx", "ny", "nz")]))
    assert list(cloud.fields) == ["red", "green", "blue", "quality"]
    assert cloud.fields["red"].dtype == np.uint8 and cloud.fields["quality"].dtype == np.float32
    np.testing.assert_array_equal(cloud.fields["quality"], vertex["quality"])


@needs_plyfile
@pytest.mark.parametrize("mode", PLY_MODES)
def test_ply_write_moves_points_adds_field_and_keeps_the_rest(tmp_path, mode):
    vertex, face = make_ply(tmp_path / "a.ply", mode)
    cloud = pio.read(tmp_path / "a.ply")
    moved = cloud.points + 0.25
    likelihood = np.linspace(0, 1, N)
    pio.write(tmp_path / "b.ply", cloud, points=moved, fields={"likelihood": likelihood})
    out = plyfile.PlyData.read(str(tmp_path / "b.ply"))
    assert (out.text, out.byte_order) == PLY_MODES[mode]
    assert out.comments == ["scanned by test"] and out.obj_info == ["unit m"]
    data = out["vertex"].data
    for name in ("nx", "ny", "nz", "red", "green", "blue", "quality"):
        assert data.dtype[name].newbyteorder("=") == vertex.dtype[name]
        np.testing.assert_array_equal(data[name], vertex[name])
    for i, c in enumerate("xyz"):
        np.testing.assert_array_equal(data[c], moved[:, i].astype(np.float32))
    assert data.dtype["likelihood"].kind == "f" and data.dtype["likelihood"].itemsize == 8
    np.testing.assert_array_equal(data["likelihood"], likelihood)
    assert len(out["face"].data) == len(face)
    for got, want in zip(out["face"].data["vertex_indices"], face["vertex_indices"], strict=True):
        np.testing.assert_array_equal(got, want)
    again = pio.read(tmp_path / "b.ply")
    np.testing.assert_array_equal(again.fields["likelihood"], likelihood)


@needs_plyfile
@pytest.mark.parametrize("mode", PLY_MODES)
def test_ply_unchanged_write_reproduces_the_file_byte_for_byte(tmp_path, mode):
    make_ply(tmp_path / "a.ply", mode)
    pio.write(tmp_path / "b.ply", pio.read(tmp_path / "a.ply"))
    pio.write(tmp_path / "c.ply", pio.read(tmp_path / "b.ply"))
    # plyfile writes ASCII floats in 18 digits, pssd_fast in the fewest that read back: an
    # ASCII file it wrote comes back byte for byte, a binary file any writer wrote.
    assert (tmp_path / "c.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    if mode != "ascii":
        assert (tmp_path / "b.ply").read_bytes() == (tmp_path / "a.ply").read_bytes()


@needs_plyfile
def test_ply_new_normals_and_replaced_field_keep_property_types(tmp_path):
    vertex = np.zeros(5, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("label", "u1")])
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")]).write(str(tmp_path / "a.ply"))
    cloud = pio.read(tmp_path / "a.ply")
    assert cloud.normals is None
    normals = np.tile([0.0, 0.0, 1.0], (5, 1))
    pio.write(tmp_path / "b.ply", cloud, normals=normals,
              fields={"label": np.arange(5.0)})
    data = plyfile.PlyData.read(str(tmp_path / "b.ply"))["vertex"].data
    assert data.dtype["nx"] == np.float64 and data.dtype["label"] == np.uint8
    np.testing.assert_array_equal(data["label"], np.arange(5))
    with pytest.raises(PointCloudFileError, match="'label' does not fit the uint8"):
        pio.write(tmp_path / "c.ply", cloud, fields={"label": np.full(5, 300.0)})


def make_rich_ply(path, mode, n=30):
    """A PLY of every part a body can hold: vertex scalars of six types, faces of 0 to 4
    indices, edges whose fixed-length lists sit between scalars, an element without rows, one
    of empty lists only, comments and obj_info."""
    rng = np.random.default_rng(1)
    vertex = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("nx", "f8"),
                                ("ny", "f8"), ("nz", "f8"), ("intensity", "u2"),
                                ("flag", "i1"), ("label", "u4"), ("offset", "i2")])
    for name in ("x", "y", "z", "nx", "ny", "nz"):
        vertex[name] = rng.normal(size=n) * 10.0 ** rng.integers(-6, 6, n)
    vertex["x"][:2] = 0.0761918, -0.0
    vertex["intensity"] = rng.integers(0, 2**16, n)
    vertex["flag"] = rng.integers(-128, 128, n)
    vertex["label"] = rng.integers(0, 2**32, n)
    vertex["offset"] = rng.integers(-2**15, 2**15, n)
    face = np.empty(n, dtype=[("vertex_indices", "O"), ("quality", "f4")])
    edge = np.empty(n // 2, dtype=[("id", "i4"), ("ends", "O"), ("weight", "f8"),
                                   ("tags", "O"), ("mark", "u1")])
    for i in range(n):
        face["vertex_indices"][i] = rng.integers(0, n, i % 5).astype(np.int32)
    face["quality"] = rng.normal(size=n)
    for i in range(n // 2):
        edge["ends"][i] = np.array([i, i + 1], np.int32)
        edge["tags"][i] = rng.normal(size=3).astype(np.float32)
    edge["id"], edge["weight"], edge["mark"] = np.arange(n // 2) - 3, rng.normal(size=n // 2), 7
    nothing = np.empty(0, dtype=[("a", "f4"), ("b", "O")])
    holes = np.empty(3, dtype=[("b", "O")])
    holes["b"] = [np.empty(0, np.int16)] * 3
    text, byte_order = PLY_MODES[mode]
    describe = plyfile.PlyElement.describe
    plyfile.PlyData([describe(vertex, "vertex", comments=["the points"]),
                     describe(face, "face", val_types={"vertex_indices": "i4"}),
                     describe(edge, "edge", len_types={"ends": "u2", "tags": "u4"},
                              val_types={"ends": "i4", "tags": "f4"}),
                     describe(nothing, "nothing", val_types={"b": "i2"}),
                     describe(holes, "holes", val_types={"b": "i2"})],
                    text=text, byte_order=byte_order, comments=["scanned by test"],
                    obj_info=["unit m", "num_cols 5"]).write(str(path))


def plyfile_read(path):
    """The reference: plyfile's own reading (its loadtxt warns of every empty list, numpy of
    values beyond float32)."""
    with warnings.catch_warnings(), np.errstate(over="ignore"):
        warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
        return plyfile.PlyData.read(str(path))


def assert_same_elements(got, want):
    """Two ``plyfile.PlyData`` hold the same elements: names, counts, dtypes, every value bit
    for bit, every list row with its dtype."""
    assert [(e.name, e.count) for e in got.elements] == [(e.name, e.count) for e in want.elements]
    for mine, theirs in zip(got.elements, want.elements):
        assert mine.data.dtype == theirs.data.dtype, mine.name
        for prop in theirs.properties:
            if isinstance(prop, plyfile.PlyListProperty):
                for a, b in zip(mine.data[prop.name], theirs.data[prop.name], strict=True):
                    assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), prop.name
            else:
                assert mine.data[prop.name].tobytes() == theirs.data[prop.name].tobytes(), prop.name


@needs_plyfile
@pytest.mark.parametrize("block", [None, 7], ids=["whole", "blocks of 7"])
@pytest.mark.parametrize("mode", PLY_MODES)
def test_ply_bodies_read_as_plyfile_reads_them_and_come_back_bit_for_bit(tmp_path, monkeypatch,
                                                                        mode, block):
    if block:  # rows written and tokens parsed a few at a time, as in large files
        monkeypatch.setattr(pio.ply, "PLY_BLOCK", block)
        monkeypatch.setattr(pio._ply_text, "PLY_TOKEN_BLOCK", block)
    # The numpy reader takes each of these files whole, plyfile's own only the reference.
    monkeypatch.setattr(pio.ply, "_read_rows", lambda *args: pytest.fail("plyfile read it"))
    make_rich_ply(tmp_path / "a.ply", mode)
    reference = plyfile_read(tmp_path / "a.ply")
    cloud = pio.read(tmp_path / "a.ply")
    assert_same_elements(cloud.source.ply, reference)
    pio.write(tmp_path / "b.ply", cloud)
    out = plyfile_read(tmp_path / "b.ply")
    assert (out.text, out.byte_order) == PLY_MODES[mode]
    assert out.comments == ["scanned by test"] and out.obj_info == ["unit m", "num_cols 5"]
    assert [e.comments for e in out.elements] == [["the points"], [], [], [], []]
    assert [str(p) for e in out.elements for p in e.properties] == [
        str(p) for e in reference.elements for p in e.properties]
    assert_same_elements(out, reference)
    assert_same_elements(pio.read(tmp_path / "b.ply").source.ply, reference)


@needs_plyfile
@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_rows_with_lists_keep_the_byte_order_of_the_file(tmp_path, order):
    # plyfile's own writer puts the scalars of rows with lists in native order; they keep the
    # file's, as their lists do.
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    header = (f"ply\nformat {fmt} 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
              f"property float z\nelement face 2\nproperty uint flags\n"
              f"property list uchar int vertex_indices\nproperty short group\nend_header\n")
    body = (struct.pack(order + "6f", *range(6)) + struct.pack(order + "IB3ih", 7, 3, 0, 1, 1, -2)
            + struct.pack(order + "IB2ih", 2**31, 2, 1, 0, 300))
    (tmp_path / "a.ply").write_bytes(header.encode() + body)
    cloud = pio.read(tmp_path / "a.ply")
    face = cloud.source.ply["face"].data
    assert face["flags"].tolist() == [7, 2**31] and face["group"].tolist() == [-2, 300]
    assert [row.tolist() for row in face["vertex_indices"]] == [[0, 1, 1], [1, 0]]
    pio.write(tmp_path / "b.ply", cloud)
    assert (tmp_path / "b.ply").read_bytes() == (tmp_path / "a.ply").read_bytes()


def shortest(value):
    """A float as the ASCII writer spells it: the shortest digits that read back (numpy's for
    float32), as Python's repr lays them out, without a trailing ".0"."""
    return repr(float(str(value))).removesuffix(".0")


@needs_plyfile
def test_ascii_ply_floats_take_the_fewest_digits_that_read_back(tmp_path):
    rng = np.random.default_rng(2)
    bits = rng.integers(0, 2**32, 20000).astype(np.uint32).view(np.float32)
    x = np.concatenate([np.array([0.0761918, 0.1, 1.0, -2.5, 100.0, 1e-05, 123456.79, 1e16,
                                  3.4028235e+38, 1e-45, 0.0, -0.0], np.float32),
                        bits[np.isfinite(bits)], rng.normal(size=2000).astype(np.float32)])
    w = np.resize(np.concatenate([[0.1, 1 / 3, 2.0, -0.0, 1e22, 5e-324, 1e-7, np.inf, -np.inf],
                                  rng.normal(size=2000)]), len(x))
    vertex = np.zeros(len(x), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("w", "f8")])
    vertex["x"], vertex["w"] = x, w
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=True).write(
        str(tmp_path / "a.ply"))
    pio.write(tmp_path / "b.ply", pio.read(tmp_path / "a.ply"))
    rows = (tmp_path / "b.ply").read_text().split("end_header\n")[1].splitlines()
    tokens = [row.split() for row in rows]
    assert [t[0] for t in tokens[:7]] == ["0.0761918", "0.1", "1", "-2.5", "100", "1e-05",
                                          "123456.79"]
    assert [t[0] for t in tokens] == [shortest(v) for v in x]
    assert [t[3] for t in tokens] == [shortest(v) for v in w]
    assert tokens[3] == ["-2.5", "0", "0", "-0"] and tokens[6] == ["123456.79", "0", "0", "1e-07"]
    back = pio.read(tmp_path / "b.ply")
    assert back.points[:, 0].astype(np.float32).tobytes() == x.tobytes()
    assert back.fields["w"].tobytes() == w.tobytes()


@needs_plyfile
def test_ascii_ply_of_short_floats_is_written_as_it_was(tmp_path):
    # A scanner's %g floats (6 digits) are their float32 values' shortest spelling: a file of
    # them comes back the same size, byte for byte.
    rng = np.random.default_rng(3)
    coords = (rng.normal(size=(50, 3)) * 0.1).astype(np.float32)
    lines = [" ".join(f"{v:g}" for v in row) for row in coords]
    lines += ["0"] * 7 + [f"1 {i}" for i in range(50)] + ["2 3 4"]
    text = ("ply\nformat ascii 1.0\nobj_info num_cols 58\nelement vertex 50\nproperty float x\n"
            "property float y\nproperty float z\nelement range_grid 58\n"
            "property list uchar int vertex_indices\nend_header\n" + "\n".join(lines) + "\n")
    (tmp_path / "a.ply").write_text(text)
    cloud = pio.read(tmp_path / "a.ply")
    pio.write(tmp_path / "b.ply", cloud)
    assert (tmp_path / "b.ply").read_text() == text
    pio.write(tmp_path / "b.ply.gz", cloud)
    assert gzip.decompress((tmp_path / "b.ply.gz").read_bytes()).decode() == text


@needs_plyfile
@pytest.mark.parametrize("last", [True, False], ids=["line end last", "no line end last"])
@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"], ids=["LF", "CRLF", "CR"])
def test_ascii_ply_spellings_read_as_plyfile_reads_them(tmp_path, monkeypatch, newline, last):
    monkeypatch.setattr(pio.ply, "_read_rows", lambda *args: pytest.fail("plyfile read it"))
    header = ["ply", "format ascii 1.0", "comment spelt in every way", "element vertex 4",
              "property float x", "property double y", "property float z", "property float q",
              "property short s", "property uchar u", "element grid 4",
              "property list uchar int indices", "element face 1",
              "property list uint float weights", "property int tail", "end_header"]
    rows = ["+1.5 -0 .5 1e40 007 255", "\t2.  1e-3\t-4E+2 Infinity  -0 0 ",
            "  3.25e+2 1.000000000000000001 1 nan +12 1", "-1E-3 -0.0 1e-50 -inf -32768 010",
            "0", "1 5", "2 +3 004", "0 ", "3 1.5 -2e2 .25 -9"]
    text = newline.join(header + rows) + (newline if last else "")
    (tmp_path / "a.ply").write_bytes(text.encode())
    assert_same_elements(pio.read(tmp_path / "a.ply").source.ply, plyfile_read(tmp_path / "a.ply"))


@needs_plyfile
@pytest.mark.parametrize("row", ["1_0 2 3", "1\x0b2 3", "0." + "0" * 40 + "1 2 3", "1 2 3\x1c"],
                         ids=["underscore", "vertical tab", "long token", "separator byte"])
def test_ascii_ply_the_numpy_reader_leaves_to_plyfile_reads_the_same(tmp_path, row):
    text = ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n0 0 0\n" + row + "\n")
    (tmp_path / "a.ply").write_text(text)
    cloud = pio.read(tmp_path / "a.ply")
    assert_same_elements(cloud.source.ply, plyfile_read(tmp_path / "a.ply"))
    assert cloud.points[1, 1:].tolist() == [2, 3]


# ---------------------------------------------------------------------------------------------
# Text


@pytest.mark.parametrize("ext", [".xyz", ".pts", ".txt"])
@pytest.mark.parametrize("ncols", [3, 6, 7])
def test_text_round_trip(tmp_path, ext, ncols):
    rng = np.random.default_rng(ncols)
    data = rng.normal(size=(N, ncols)) * 1000
    if ncols == 6:  # unit vectors in columns 4-6 of six unnamed ones are normals
        data[:, 3:] /= np.linalg.norm(data[:, 3:], axis=1, keepdims=True)
    lines = ["# from a scanner", "# second comment line"]
    if ext == ".pts":
        lines.append(str(N))
    lines += [" ".join(repr(float(v)) for v in row) for row in data]
    (tmp_path / f"a{ext}").write_text("\n".join(lines) + "\n")
    with (pytest.warns(pio.PointCloudWarning, match=r"columns 4-6 read as nx, ny, nz \(unit")
          if ncols == 6 else contextlib.nullcontext()):
        cloud = pio.read(tmp_path / f"a{ext}")
    assert cloud.format == "xyz"
    np.testing.assert_array_equal(cloud.points, data[:, :3])
    if ncols == 6:
        np.testing.assert_array_equal(cloud.normals, data[:, 3:])
        assert cloud.fields == {}
    else:
        assert cloud.normals is None
        # Seven unnamed PTS columns are Leica's x y z intensity r g b.
        names = (["intensity", "red", "green", "blue"] if ext == ".pts" and ncols == 7
                 else [f"col{i}" for i in range(3, ncols)])
        assert list(cloud.fields) == names
        for i, name in enumerate(names, 3):
            np.testing.assert_array_equal(cloud.fields[name], data[:, i])
    pio.write(tmp_path / f"b{ext}", cloud)
    text = (tmp_path / f"b{ext}").read_text()
    count = f"{N}\n" if ext == ".pts" else ""  # a PTS file's first line
    assert text.startswith(count + "# from a scanner\n# second comment line\n")
    back = pio.read(tmp_path / f"b{ext}")
    np.testing.assert_array_equal(back.points, cloud.points)
    if ncols == 6:
        np.testing.assert_array_equal(back.normals, cloud.normals)
    assert list(back.fields) == list(cloud.fields)
    for name, values in cloud.fields.items():
        np.testing.assert_array_equal(back.fields[name], values)


@needs_plyfile
def test_text_output_names_its_columns_and_reads_them_back(tmp_path):
    make_ply(tmp_path / "a.ply")
    cloud = pio.read(tmp_path / "a.ply")
    likelihood = np.random.default_rng(1).random(N)
    # PTS puts Leica's colour columns right after x y z.
    for ext, names in ((".xyz", "x y z nx ny nz red green blue quality likelihood"),
                       (".pts", "x y z red green blue nx ny nz quality likelihood")):
        pio.write(tmp_path / f"b{ext}", cloud, fields={"likelihood": likelihood})
        lines = (tmp_path / f"b{ext}").read_text().splitlines()
        if ext == ".pts":  # the point count first, as Leica-layout readers take it
            assert lines.pop(0) == str(N)
        assert lines[0] == "# " + names
        assert len(lines) == N + 1 and len(lines[1].split()) == 11
        back = pio.read(tmp_path / f"b{ext}")
        np.testing.assert_array_equal(back.points, cloud.points)
        np.testing.assert_array_equal(back.normals, cloud.normals)
        np.testing.assert_array_equal(back.fields["likelihood"], likelihood)
        np.testing.assert_array_equal(back.fields["red"], cloud.fields["red"])
        # float32 values come back equal once cast to their own type
        np.testing.assert_array_equal(back.fields["quality"].astype(np.float32),
                                      cloud.fields["quality"])


def test_text_comments_are_kept_byte_for_byte_and_extensions_ignore_case(tmp_path):
    raw = b"# Messstation K\xf6ln (latin-1), \xe2\x82\xac utf-8\n1 2 3\n4 5 6\n"
    (tmp_path / "A.XYZ").write_bytes(raw)
    cloud = pio.read(tmp_path / "A.XYZ")
    pio.write(tmp_path / "B.TXT", cloud)
    assert (tmp_path / "B.TXT").read_bytes() == raw.replace(b"\n1 2 3", b"\n# x y z\n1 2 3") \
        .replace(b"1 2 3\n4 5 6", b"1.0 2.0 3.0\n4.0 5.0 6.0")


def test_pts_of_unnamed_columns_stays_strict_pts(tmp_path):
    (tmp_path / "a.pts").write_text("2\n1 2 3 10 20 30 40\n4 5 6 11 21 31 41\n")
    pio.write(tmp_path / "b.pts", pio.read(tmp_path / "a.pts"))
    # Intensity and colours are integers and stay so.
    assert (tmp_path / "b.pts").read_text() == "2\n1.0 2.0 3.0 10 20 30 40\n" \
                                               "4.0 5.0 6.0 11 21 31 41\n"


# ---------------------------------------------------------------------------------------------
# NPY / NPZ


@pytest.mark.parametrize("ncols", [3, 6])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_npy_round_trip_keeps_dtype(tmp_path, ncols, dtype):
    arr = np.random.default_rng(0).normal(size=(N, ncols)).astype(dtype)
    np.save(tmp_path / "a.npy", arr)
    cloud = pio.read(tmp_path / "a.npy")
    np.testing.assert_array_equal(cloud.points, arr[:, :3])
    assert (cloud.normals is None) == (ncols == 3)
    pio.write(tmp_path / "b.npy", cloud)
    back = np.load(tmp_path / "b.npy")
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, arr)


def test_npy_output_warns_that_normals_are_dropped_unless_it_had_them(tmp_path):
    points, normals = np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1))
    with pytest.warns(pio.PointCloudWarning, match=r"\.npy cannot hold normals;"):
        pio.write(tmp_path / "b.npy", pio.PointCloud(points, normals))
    assert np.load(tmp_path / "b.npy").shape == (4, 3)
    assert not pio.holds_normals(tmp_path / "b.npy", pio.PointCloud(points, normals))
    np.save(tmp_path / "six.npy", np.hstack([points, normals]))
    six = pio.read(tmp_path / "six.npy")
    assert pio.holds_normals(tmp_path / "c.npy", six) and pio.holds_normals("c.ply", six)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pio.write(tmp_path / "c.npy", six)
    assert np.load(tmp_path / "c.npy").shape == (4, 6)


def test_npy_output_warns_that_fields_are_dropped(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((4, 3)))
    cloud = pio.read(tmp_path / "a.npy")
    with pytest.warns(pio.PointCloudWarning, match=r"cannot hold fields \['likelihood'\]"):
        pio.write(tmp_path / "b.npy", cloud, fields={"likelihood": np.ones(4)})
    assert np.load(tmp_path / "b.npy").shape == (4, 3)


@pytest.mark.parametrize("compressed", [False, True])
def test_npz_round_trip_keeps_fields_extras_and_compression(tmp_path, compressed):
    rng = np.random.default_rng(0)
    arrays = {"points": rng.normal(size=(N, 3)).astype(np.float32),
              "normals": rng.normal(size=(N, 3)),
              "intensity": rng.integers(0, 1000, N).astype(np.int16),
              "labels": rng.integers(0, 5, N).astype(np.uint8),
              "transform": np.eye(4)}
    (np.savez_compressed if compressed else np.savez)(tmp_path / "a.npz", **arrays)
    cloud = pio.read(tmp_path / "a.npz")
    assert set(cloud.fields) == {"intensity", "labels"}
    assert cloud.fields["intensity"].dtype == np.int16
    np.testing.assert_array_equal(cloud.normals, arrays["normals"])
    pio.write(tmp_path / "b.npz", cloud, fields={"likelihood": np.arange(N) / N})
    with np.load(tmp_path / "b.npz") as back:
        assert set(back.files) == set(arrays) | {"likelihood"}
        for key, values in arrays.items():
            assert back[key].dtype == values.dtype
            np.testing.assert_array_equal(back[key], values)
        np.testing.assert_array_equal(back["likelihood"], np.arange(N) / N)
    import zipfile
    with zipfile.ZipFile(tmp_path / "b.npz") as zf:
        stored = {i.compress_type == zipfile.ZIP_STORED for i in zf.infolist()}
    assert stored == {not compressed}


# ---------------------------------------------------------------------------------------------
# LAS / LAZ


def las_dims(las):
    return [d for d in las.point_format.dimension_names if d not in ("X", "Y", "Z")]


@needs_laspy
@pytest.mark.parametrize("point_format", [3, 7])
@pytest.mark.parametrize("ext", LAS_EXTS)
def test_las_write_keeps_records_header_and_vlrs(tmp_path, ext, point_format):
    original = make_las(tmp_path / f"a{ext}", point_format=point_format)
    cloud = pio.read(tmp_path / f"a{ext}")
    assert cloud.format == "las" and cloud.normals is None
    np.testing.assert_array_equal(cloud.points, original.xyz)
    assert cloud.fields["intensity"].dtype == np.uint16
    assert cloud.fields["gps_time"].dtype == np.float64
    np.testing.assert_array_equal(cloud.fields["classification"], original.classification)
    moved = cloud.points + np.array([0.5, -0.25, 0.125])
    likelihood = np.linspace(0, 1, N)
    pio.write(tmp_path / f"b{ext}", cloud, points=moved, fields={"likelihood": likelihood})
    out = laspy.read(str(tmp_path / f"b{ext}"))
    assert out.header.point_format.id == point_format
    assert out.header.version == original.header.version
    np.testing.assert_array_equal(out.header.scales, [0.001] * 3)
    np.testing.assert_array_equal(out.header.offsets, [500000.0, 4000000.0, 300.0])
    assert out.header.are_points_compressed == (ext == ".laz")
    for name in las_dims(original):
        np.testing.assert_array_equal(np.asarray(out[name]), np.asarray(original[name]))
    np.testing.assert_array_equal(out.X, original.X + 500)
    np.testing.assert_array_equal(out.Y, original.Y - 250)
    np.testing.assert_array_equal(out.Z, original.Z + 125)
    assert out["likelihood"].dtype == np.float64
    np.testing.assert_array_equal(out["likelihood"], likelihood)
    assert [(v.user_id, v.record_id, v.record_data) for v in out.vlrs
            if v.user_id == "pssd_test"] == [("pssd_test", 42, b"vlr payload")]
    assert [(v.record_id, v.record_data) for v in out.evlrs] == [(43, b"evlr payload")]
    back = pio.read(tmp_path / f"b{ext}")
    np.testing.assert_array_equal(back.fields["likelihood"], likelihood)
    # Writing leaves the cloud as it was: a second write does not see the first's additions.
    pio.write(tmp_path / f"c{ext}", cloud)
    again = laspy.read(str(tmp_path / f"c{ext}"))
    assert list(again.point_format.dimension_names) == list(original.point_format.dimension_names)
    assert [v.record_id for v in again.vlrs] == [v.record_id for v in original.vlrs]
    np.testing.assert_array_equal(again.X, original.X)


@needs_laspy
@pytest.mark.parametrize("scale", [1e-5, 1e-3])
def test_las_unmodified_utm_coordinates_round_trip_bit_exactly(tmp_path, scale):
    # Integers over most of the int32 range: eastings/northings far from the offset.
    original = make_las(tmp_path / "a.las", n=2000, scale=scale, span=2**31 - 2, seed=3)
    pio.write(tmp_path / "b.las", pio.read(tmp_path / "a.las"))
    out = laspy.read(str(tmp_path / "b.las"))
    for c in "XYZ":
        np.testing.assert_array_equal(out[c], original[c])


@needs_laspy
def test_las_small_moves_survive_quantisation_when_the_scale_allows(tmp_path):
    fine = make_las(tmp_path / "fine.las", scale=1e-5)
    cloud = pio.read(tmp_path / "fine.las")
    pio.write(tmp_path / "fine_moved.las", cloud, points=cloud.points + np.array([1e-4, 0, -1e-4]))
    out = laspy.read(str(tmp_path / "fine_moved.las"))
    np.testing.assert_array_equal(out.X, fine.X + 10)
    np.testing.assert_array_equal(out.Y, fine.Y)
    np.testing.assert_array_equal(out.Z, fine.Z - 10)
    np.testing.assert_allclose(pio.read(tmp_path / "fine_moved.las").points - cloud.points,
                               np.tile([1e-4, 0, -1e-4], (N, 1)), rtol=0, atol=1e-9)

    mm = make_las(tmp_path / "mm.las", scale=1e-3)
    cloud = pio.read(tmp_path / "mm.las")
    pio.write(tmp_path / "mm_moved.las", cloud, points=cloud.points + np.array([1e-4, 6e-4, 0]))
    out = laspy.read(str(tmp_path / "mm_moved.las"))
    np.testing.assert_array_equal(out.X, mm.X)  # 0.1 mm rounds away at 1 mm resolution
    np.testing.assert_array_equal(out.Y, mm.Y + 1)  # 0.6 mm rounds to 1 mm


@needs_plyfile
@needs_laspy
def test_las_normals_and_fields_from_another_format(tmp_path):
    make_ply(tmp_path / "a.ply")
    cloud = pio.read(tmp_path / "a.ply")
    pio.write(tmp_path / "b.las", cloud, fields={"intensity": np.arange(N)})
    back = pio.read(tmp_path / "b.las")
    scales = laspy.read(str(tmp_path / "b.las")).header.scales
    assert np.all(np.abs(back.points - cloud.points) <= scales / 2 * (1 + 1e-9))
    np.testing.assert_array_equal(back.normals, cloud.normals)
    assert back.fields["red"].dtype == np.uint8 and back.fields["quality"].dtype == np.float32
    np.testing.assert_array_equal(back.fields["quality"], cloud.fields["quality"])
    assert back.fields["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(back.fields["intensity"], np.arange(N))


@needs_laspy
def test_a_new_las_file_refuses_a_scale_coarser_than_the_spacing_allows(tmp_path):
    """One row 1e15 away stretched a new file's extent, and its scale (1e6) wrote every other
    point at one position without a word; 1e6 away the scale (0.001) leaves thousands of steps
    across their spacing (about 7), and the file is written."""
    rng = np.random.default_rng(8)
    points = np.column_stack([rng.uniform(0, 1000, (5000, 2)), rng.normal(0, 0.1, 5000)])
    for far, scale in ((1e15, "1e\\+06"), (1e6, "0.001")):
        cloud = PointCloud(np.vstack([points, [far, far, far]]))
        if far > 1e9:
            with pytest.raises(PointCloudFileError, match=rf"b\.las: .* need a scale of {scale}: "
                                                          r"fewer than 100 steps across"):
                pio.write(tmp_path / "b.las", cloud)
            assert not (tmp_path / "b.las").exists()
        else:
            pio.write(tmp_path / "b.las", cloud)
            assert laspy.read(str(tmp_path / "b.las")).header.scales.max() == float(scale)


# ---------------------------------------------------------------------------------------------
# Errors


def test_unknown_extension_lists_the_supported_ones(tmp_path):
    (tmp_path / "a.dat").write_text("0 0 0\n")
    with pytest.raises(PointCloudFileError, match=r"a\.dat: unknown extension '\.dat'; "
                                                   r"supported: \.csv, \.csv\.gz, \.las"):
        pio.read(tmp_path / "a.dat")
    cloud = PointCloud(np.zeros((2, 3)))
    with pytest.raises(PointCloudFileError, match=r"unknown extension '\.e57'"):
        pio.write(tmp_path / "a.e57", cloud)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(PointCloudFileNotFoundError, match=r"nope\.ply: no such file") as info:
        pio.read(tmp_path / "nope.ply")
    assert isinstance(info.value, FileNotFoundError)
    (tmp_path / "scan.xyz").mkdir()
    with pytest.raises(PointCloudFileError, match=r"scan\.xyz: is a directory"):
        pio.read(tmp_path / "scan.xyz")


@pytest.mark.parametrize("text, match", [
    ("1 2 3\n4 5 6\n7 abc 9\n", "bad number 'abc' on line 3"),
    ("# c\n1 2 3\n4 5\n", "line 3 has 2 columns; the first data line has 3"),
    ("1 2\n3 4\n", "line 1 has 2 columns; x y z need 3"),
    ("1 2 3\n4 nan 6\ninf 1 1\n7 8 9\n", "2 of 4 points have NaN or Inf coordinates"),
    ("# only a comment\n\n", "holds no points"),
    ("3\n1.5 2.5 3.5\n4.5 5.5 6.5\n", "first line says 3 points but the file holds 2"),
    (f"{10**9}\n1 2 3\n", "first line says 1,000,000,000 points, more than"),
    # Rows that do not read as numbers, after a column-name line: named, not "no points".
    ("x;y;z\n1.234,5;2;3\n", "no line holds a row of numbers; line 2 reads as text: "
                             "'1.234,5;2;3'"),
    ('"x","y","z"\n"a","2","3"\n', "line 2 reads as text: '\"a\",\"2\",\"3\"'"),
])
def test_text_errors(tmp_path, text, match):
    (tmp_path / "a.pts").write_text(text)
    with pytest.raises(PointCloudFileError, match=match) as info:
        pio.read(tmp_path / "a.pts")
    message = str(info.value)
    assert message.startswith(str(tmp_path / "a.pts")) and "\n" not in message


def test_a_separator_ending_every_row_opens_no_column(tmp_path):
    """Some exporters end each row with its separator (``1,2,3,``)."""
    (tmp_path / "a.csv").write_text("x;y;z;i;\n1;2;3;4;\n5;6;7;8;\n")
    cloud = pio.read(tmp_path / "a.csv")
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [4, 8])
    (tmp_path / "b.csv").write_text("1,2,3,\n4,5,6,\n")
    np.testing.assert_array_equal(pio.read(tmp_path / "b.csv").points, [[1, 2, 3], [4, 5, 6]])


def test_a_byte_order_mark_is_not_part_of_the_first_name(tmp_path):
    """Spreadsheets write "CSV UTF-8" with a byte order mark before the column names."""
    (tmp_path / "a.csv").write_text("\ufeffx,y,z,intensity\n1,2,3,4\n5,6,7,8\n",
                                    encoding="utf-8")
    cloud = pio.read(tmp_path / "a.csv")
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [4, 8])


def test_decimal_commas_between_semicolons_are_read(tmp_path):
    """Spreadsheets where the comma is the decimal mark write ``1,5;2,25``; whole numbers
    stay integers."""
    (tmp_path / "a.csv").write_text("x;y;z;intensity\n1,5;-2,25;3;7\n4;5,125;6e-1;8\n")
    cloud = pio.read(tmp_path / "a.csv")
    np.testing.assert_array_equal(cloud.points, [[1.5, -2.25, 3], [4, 5.125, 0.6]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [7, 8])
    assert cloud.fields["intensity"].dtype.kind == "i"
    (tmp_path / "b.csv").write_text("1;2;3\n1,5;2;3\n")  # the first row has no comma
    with pytest.raises(PointCloudFileError, match=r"bad number '1,5' on line 2"):
        pio.read(tmp_path / "b.csv")


def test_quoted_values_and_names_are_read(tmp_path):
    """Some exporters quote every value, names and numbers alike."""
    (tmp_path / "a.csv").write_text('"x","y","z","intensity"\n"1.5","2","3","7"\n'
                                    '"4","5","6","8"\n')
    cloud = pio.read(tmp_path / "a.csv")
    np.testing.assert_array_equal(cloud.points, [[1.5, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [7, 8])
    (tmp_path / "b.csv").write_text('"x";"y";"z"\n"1,5";"2";"3"\n')
    np.testing.assert_array_equal(pio.read(tmp_path / "b.csv").points, [[1.5, 2, 3]])


@pytest.mark.parametrize("mark, codec", [(b"\xff\xfe", "utf-16-le"), (b"\xfe\xff", "utf-16-be")])
def test_utf16_text_after_its_byte_order_mark_is_read(tmp_path, mark, codec):
    """PowerShell's ``>`` and Notepad's "Unicode" write UTF-16, little-endian on Windows."""
    text = "# scan\r\nx y z intensity\r\n1.5 2 3 4\r\n5 6 7 8\r\n"
    (tmp_path / "a.xyz").write_bytes(mark + text.encode(codec))
    cloud = pio.read(tmp_path / "a.xyz")
    np.testing.assert_array_equal(cloud.points, [[1.5, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [4, 8])


@needs_plyfile
def test_ascii_ply_bad_value_names_the_line(tmp_path):
    (tmp_path / "a.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 0\n1 abc 1\n2 2 2\n")
    with pytest.raises(PointCloudFileError, match=r"line 9 \('vertex' row 1\), property 'y'"):
        pio.read(tmp_path / "a.ply")


ASCII_HEAD = ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
              "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
              "end_header\n")


@needs_plyfile
@pytest.mark.parametrize("body, match", [
    ("0 0 0\n1 1\n3 0 1 1\n2 0 1\n",
     r"early end-of-line on line 11 \('vertex' row 1\), property 'z'"),
    ("0 0 0\n1 1 1 1\n3 0 1 1\n2 0 1\n", r"expected end-of-line on line 11 \('vertex' row 1\)"),
    ("0 0 0\n1 1e 1\n3 0 1 1\n2 0 1\n",
     r"malformed input on line 11 \('vertex' row 1\), property 'y'"),
    ("0 0 0\n1 1 1\n3 0 1\n2 0 1\n",
     r"early end-of-line on line 12 \('face' row 0\), property 'vertex_indices'"),
    ("0 0 0\n1 1 1\n3 0 1 2.5\n2 0 1\n",
     r"malformed input on line 12 \('face' row 0\), property 'vertex_indices'"),
    ("0 0 0\n1 1 1\n-1 0\n2 0 1\n", "does not fit the type of its PLY property"),
    ("0 0 0\n1 1 1\n300 0 1\n2 0 1\n", "does not fit the type of its PLY property"),
    ("0 0 0\n1 1 1\n3 0 1 2\n", "truncated: element 'face' ends after 1 of 2 rows"),
    ("0 0 0\n1 1 1\n3 0 1 2\n\xe9\n", "non-ASCII bytes"),
], ids=["short row", "long row", "bad value", "short list", "float in an int list",
        "negative length", "length beyond its type", "missing row", "non-ASCII"])
def test_malformed_ascii_ply_bodies_say_where(tmp_path, body, match):
    (tmp_path / "a.ply").write_bytes((ASCII_HEAD + body).encode("latin-1"))
    with pytest.raises(PointCloudFileError, match=match) as info:
        pio.read(tmp_path / "a.ply")
    assert str(info.value).startswith(str(tmp_path / "a.ply")) and "\n" not in str(info.value)


@needs_plyfile
@pytest.mark.parametrize("length_type, cut, match", [
    ("uchar", 7, "truncated: element 'face' ends after 1 of 2 rows"),
    ("uchar", 10, "truncated: element 'face' ends after 0 of 2 rows"),
    ("int", 2, "truncated: element 'face' ends after 1 of 2 rows"),
    ("char", 0, "truncated: element 'face' ends after 1 of 2 rows"),  # a length of -1
])
def test_truncated_binary_ply_lists_say_which_row(tmp_path, length_type, cut, match):
    code = {"uchar": "B", "char": "b", "int": "i"}[length_type]
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
              "property float y\nproperty float z\nelement face 2\n"
              f"property list {length_type} int vertex_indices\nend_header\n").encode()
    second = [-1, 5, 6] if length_type == "char" else [2, 5, 6]
    body = (struct.pack("<6f", *range(6)) + struct.pack(f"<{code}3i", 3, 0, 1, 1)
            + struct.pack(f"<{code}2i", *second))
    (tmp_path / "a.ply").write_bytes(header + body[:len(body) - cut])
    with pytest.raises(PointCloudFileError, match=match):
        pio.read(tmp_path / "a.ply")


@needs_plyfile
@pytest.mark.parametrize("mode", ["binary_le", "ascii"])
def test_truncated_ply_vertices(tmp_path, mode):
    make_ply(tmp_path / "a.ply", mode, n=400)
    data = (tmp_path / "a.ply").read_bytes()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    (tmp_path / "cut.ply").write_bytes(data[:header_end + 100])
    with pytest.raises(PointCloudFileError, match="header claims 400 'vertex' elements"):
        pio.read(tmp_path / "cut.ply")


@needs_plyfile
def test_range_grid_ply_reads_without_a_note_and_keeps_its_grid(tmp_path):
    # A raw range scan as the Stanford scans come (CRLF, a space after each vertex row):
    # vertices, then a row per scanner pixel listing the vertex seen there, "0" where none.
    rows = ["0.5 1.5 2.5 ", "-1 0 1 ", "3 4 5.25 ", "1 0", "0", "1 1", "0", "0", "1 2"]
    (tmp_path / "grid.ply").write_bytes("\r\n".join([
        "ply", "format ascii 1.0", "obj_info num_cols 3", "obj_info num_rows 2",
        "element vertex 3", "property float x", "property float y", "property float z",
        "element range_grid 6", "property list uchar int vertex_indices", "end_header",
        *rows, ""]).encode())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cloud = pio.read(tmp_path / "grid.ply")
    assert [str(w.message) for w in caught] == []
    assert np.array_equal(cloud.points, [[0.5, 1.5, 2.5], [-1, 0, 1], [3, 4, 5.25]])
    assert pio.describe(cloud) == ["other elements: range_grid (6)"]
    pio.write(tmp_path / "out.ply", cloud, points=cloud.points + 1)
    out = plyfile.PlyData.read(str(tmp_path / "out.ply"))
    assert out.obj_info == ["num_cols 3", "num_rows 2"]
    assert [r.tolist() for r in out["range_grid"]["vertex_indices"]] == [[0], [], [1], [], [],
                                                                          [2]]
    # Dropping a vertex empties its grid cell and renumbers the others (a scanner's grid).
    kept = pio.select(cloud, [0, 2])
    pio.write(tmp_path / "kept.ply", kept)
    out = plyfile.PlyData.read(str(tmp_path / "kept.ply"))
    assert out["vertex"].count == 2
    assert [r.tolist() for r in out["range_grid"]["vertex_indices"]] == [[0], [], [], [], [],
                                                                          [1]]


@needs_plyfile
def test_faces_of_dropped_vertices_are_dropped_with_a_note(tmp_path):
    make_ply(tmp_path / "a.ply")
    cloud = pio.read(tmp_path / "a.ply")
    faces = plyfile.PlyData.read(str(tmp_path / "a.ply"))["face"]["vertex_indices"]
    drop = int(faces[0][0])
    rows = np.setdiff1d(np.arange(len(cloud)), [drop])
    with pytest.warns(pio.PointCloudWarning, match="face rows index dropped vertices"):
        kept = pio.select(cloud, rows)
    pio.write(tmp_path / "b.ply", kept)
    out = plyfile.PlyData.read(str(tmp_path / "b.ply"))
    renumber = {old: new for new, old in enumerate(rows)}
    want = [[renumber[v] for v in f] for f in faces if drop not in f]
    assert [f.tolist() for f in out["face"]["vertex_indices"]] == want


@needs_plyfile
def test_truncated_ply_faces(tmp_path):
    make_ply(tmp_path / "a.ply", "binary_le")
    data = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-7])
    with pytest.raises(PointCloudFileError, match=f"truncated: element 'face' ends after "
                                                  f"{N - 3} of {N - 2} rows"):
        pio.read(tmp_path / "cut.ply")


@needs_plyfile
@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_ply_claiming_a_billion_vertices_fails_fast_without_allocating(tmp_path, fmt):
    (tmp_path / "a.ply").write_bytes(
        f"ply\nformat {fmt} 1.0\nelement vertex {10**9}\nproperty float x\n"
        f"property float y\nproperty float z\nend_header\n".encode() + b"0" * 64)
    tracemalloc.start()
    try:
        with pytest.raises(PointCloudFileError, match="header claims 1,000,000,000 'vertex'"):
            pio.read(tmp_path / "a.ply")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20


@needs_plyfile
def test_ply_without_vertices_or_coordinates(tmp_path):
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                                    "property float y\nproperty float z\nend_header\n")
    with pytest.raises(PointCloudFileError, match="holds no points"):
        pio.read(tmp_path / "a.ply")
    (tmp_path / "b.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                                    "property float y\nend_header\n1 2\n")
    with pytest.raises(PointCloudFileError, match="vertex element has no z property"):
        pio.read(tmp_path / "b.ply")


@needs_laspy
@pytest.mark.parametrize("ext", LAS_EXTS)
def test_truncated_las(tmp_path, ext):
    make_las(tmp_path / f"a{ext}", n=500)
    data = (tmp_path / f"a{ext}").read_bytes()
    (tmp_path / f"cut{ext}").write_bytes(data[:len(data) // 2])
    # The LAZ file's chunk table (at the end of its points) is cut off: refused before lazrs
    # reads it.
    match = "header claims 500 points" if ext == ".las" else r"chunk table .* \(truncated"
    with pytest.raises(PointCloudFileError, match=match):
        pio.read(tmp_path / f"cut{ext}")


@needs_laspy
@pytest.mark.parametrize("ext", LAS_EXTS)
def test_las_claiming_a_billion_points_fails_with_bounded_memory(tmp_path, ext):
    make_las(tmp_path / f"a{ext}")
    data = bytearray((tmp_path / f"a{ext}").read_bytes())
    data[247:255] = struct.pack("<Q", 10**9)  # LAS 1.4 64-bit point count
    (tmp_path / f"big{ext}").write_bytes(bytes(data))
    tracemalloc.start()
    try:
        with pytest.raises(PointCloudFileError, match=r"1,000,000,000 points|truncated or corrupt"):
            pio.read(tmp_path / f"big{ext}")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # One read piece at most (2**20 records of 34 bytes), not 34 GB.
    assert peak < (8 if ext == ".las" else 64) * 2**20


def test_npy_errors(tmp_path):
    np.save(tmp_path / "a.npy", np.ones((100, 3)))
    data = (tmp_path / "a.npy").read_bytes()
    (tmp_path / "cut.npy").write_bytes(data[:-10])
    with pytest.raises(PointCloudFileError, match=r"claims shape \(100, 3\) \(2,400 bytes\)"):
        pio.read(tmp_path / "cut.npy")
    with open(tmp_path / "big.npy", "wb") as fh:
        np.lib.format.write_array_header_1_0(
            fh, {"descr": "<f8", "fortran_order": False, "shape": (10**9, 3)})
        fh.write(b"\0" * 48)
    tracemalloc.start()
    try:
        with pytest.raises(PointCloudFileError, match=r"claims shape \(1000000000, 3\)"):
            pio.read(tmp_path / "big.npy")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20
    np.save(tmp_path / "bad.npy", np.ones((5, 4)))
    with pytest.raises(PointCloudFileError, match=r"expected an \(n, 3\) or \(n, 6\)"):
        pio.read(tmp_path / "bad.npy")
    np.save(tmp_path / "empty.npy", np.ones((0, 3)))
    with pytest.raises(PointCloudFileError, match="holds no points"):
        pio.read(tmp_path / "empty.npy")
    (tmp_path / "text.npy").write_text("1 2 3\n")
    with pytest.raises(PointCloudFileError, match=r"not a valid \.npy array"):
        pio.read(tmp_path / "text.npy")


def test_npz_errors(tmp_path):
    np.savez(tmp_path / "a.npz", points=np.ones((100, 3)))
    data = (tmp_path / "a.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    with pytest.raises(PointCloudFileError, match=r"not a readable \.npz"):
        pio.read(tmp_path / "cut.npz")
    np.savez(tmp_path / "b.npz", xyz=np.ones((4, 3)))
    with pytest.raises(PointCloudFileError, match="needs a numeric \\(n, 3\\) 'points' array"):
        pio.read(tmp_path / "b.npz")


def test_missing_optional_libraries_say_how_to_install(tmp_path, monkeypatch):
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\n"
                                    "property float x\nproperty float y\nproperty float z\n"
                                    "end_header\n1 2 3\n")
    (tmp_path / "a.las").write_bytes(b"LASF")  # refused before it is opened
    cloud = PointCloud(np.arange(3.0 * N).reshape(N, 3), fields={"f": np.ones(N)})
    monkeypatch.setitem(sys.modules, "plyfile", None)
    monkeypatch.setitem(sys.modules, "laspy", None)
    install = r"pip install 'pssd_fast\[io\]'"
    with pytest.raises(ImportError, match=f"needs plyfile: {install}"):
        pio.read(tmp_path / "a.ply")
    with pytest.raises(ImportError, match=f"needs plyfile: {install}"):
        pio.write(tmp_path / "b.ply", cloud)
    with pytest.raises(ImportError, match=rf"needs laspy\[lazrs\]: {install}"):
        pio.read(tmp_path / "a.las")
    # NPY, NPZ and text need numpy only.
    plain = dataclasses.replace(cloud, fields={})
    for ext in (".npy", ".npz", ".xyz"):
        pio.write(tmp_path / f"b{ext}", plain)
        assert len(pio.read(tmp_path / f"b{ext}")) == N
    assert not (tmp_path / "b.ply").exists()


@needs_laspy
def test_laz_without_lazrs_says_how_to_install(tmp_path, monkeypatch):
    from laspy._compression import lazrsbackend

    monkeypatch.setattr(lazrsbackend, "lazrs", None)
    with pytest.raises(ImportError, match=r"laspy\[lazrs\].*pip install 'pssd_fast\[io\]'"):
        pio.write(tmp_path / "a.laz", PointCloud(np.zeros((2, 3))))


# ---------------------------------------------------------------------------------------------
# Atomic writing and overwriting


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".partial" in p.name)


def write_some_then_fail(fh, *args, **kwargs):
    fh.write(b"partial output")
    raise RuntimeError("disk full")


def method_writing_some_then_failing(self, fh, *args, **kwargs):
    write_some_then_fail(fh)


@pytest.mark.parametrize("ext, target, replacement", [
    pytest.param(".ply", "pssd_fast.io.ply._write", method_writing_some_then_failing,
                 marks=needs_plyfile),
    pytest.param(".las", "laspy.LasData.write", method_writing_some_then_failing,
                 marks=needs_laspy),
    (".npz", "numpy.savez", write_some_then_fail),
    (".npy", "numpy.save", write_some_then_fail),
])
def test_failed_write_leaves_no_output_and_no_temporary_file(tmp_path, monkeypatch, ext, target,
                                                             replacement):
    # Normals where the format holds them (.npy holds points only, with a note).
    cloud = PointCloud(np.arange(3.0 * N).reshape(N, 3),
                       normals=None if ext == ".npy" else np.ones((N, 3)))
    monkeypatch.setattr(target, replacement)
    with pytest.raises(RuntimeError, match="disk full"):
        pio.write(tmp_path / f"b{ext}", cloud)
    assert not (tmp_path / f"b{ext}").exists()
    assert leftovers(tmp_path) == []


def test_failed_overwrite_keeps_the_old_file(tmp_path, monkeypatch):
    (tmp_path / "a.xyz").write_text("1 2 3\n")
    old = (tmp_path / "a.xyz").read_bytes()
    cloud = PointCloud(np.zeros((2, 3)))
    monkeypatch.setattr(pio.text, "decimal_strings", lambda values: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        pio.write(tmp_path / "a.xyz", cloud, overwrite=True)
    assert (tmp_path / "a.xyz").read_bytes() == old
    assert leftovers(tmp_path) == []


def test_existing_output_needs_overwrite(tmp_path):
    cloud = PointCloud(np.arange(6.0).reshape(2, 3))
    pio.write(tmp_path / "a.xyz", cloud)
    with pytest.raises(FileExistsError, match=r"a\.xyz: already exists; pass overwrite=True "
                                              r"\(--force"):
        pio.write(tmp_path / "a.xyz", cloud)
    pio.write(tmp_path / "a.xyz", cloud, points=cloud.points + 1, overwrite=True)
    np.testing.assert_array_equal(pio.read(tmp_path / "a.xyz").points, cloud.points + 1)


def test_existing_output_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    (tmp_path / "a.npy").write_bytes(b"old")
    monkeypatch.setattr(np, "save", write_some_then_fail)
    with pytest.raises(FileExistsError, match="already exists"):
        pio.write(tmp_path / "a.npy", PointCloud(np.zeros((2, 3))))
    assert (tmp_path / "a.npy").read_bytes() == b"old"
    assert leftovers(tmp_path) == []


@needs_plyfile
def test_input_is_never_modified_and_not_overwritten_by_default(tmp_path, monkeypatch):
    make_ply(tmp_path / "a.ply")
    before = (tmp_path / "a.ply").read_bytes()
    monkeypatch.chdir(tmp_path)
    cloud = pio.read("a.ply")
    pio.write(tmp_path / "b.ply", cloud, points=cloud.points * 2, fields={"f": np.ones(N)})
    assert (tmp_path / "a.ply").read_bytes() == before
    with pytest.raises(FileExistsError, match=r"is the file this cloud was read from.*--force"):
        pio.write(tmp_path / "a.ply", cloud, points=cloud.points * 2)
    assert (tmp_path / "a.ply").read_bytes() == before
    pio.write("a.ply", cloud, points=cloud.points * 2, overwrite=True)
    np.testing.assert_array_equal(pio.read("a.ply").points, (cloud.points * 2).astype(np.float32))


@pytest.mark.parametrize("kwargs, match", [
    ({"points": np.zeros((3, 3))}, r"points must be a real array of shape \(4, 3\)"),
    ({"points": np.full((4, 3), np.nan)}, "4 of 4 points have NaN or Inf"),
    ({"normals": np.zeros((4, 2))}, r"normals must be a real array of shape \(4, 3\)"),
    ({"fields": {"likelihood": np.ones(5)}}, r"'likelihood' must be a numeric array of shape"),
    ({"fields": {"nx": np.ones(4)}}, r"\['nx'\] are reserved"),
    ({"fields": {"my field": np.ones(4)}}, "cannot hold names with spaces"),
])
def test_write_argument_errors(tmp_path, kwargs, match):
    with pytest.raises(PointCloudFileError, match=match):
        pio.write(tmp_path / "a.ply", PointCloud(np.zeros((4, 3))), **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_an_array_or_a_result_is_written_as_its_points_and_normals(tmp_path):
    import pssd_fast
    from pssd_fast import datasets
    points = np.arange(12.0).reshape(4, 3)
    pio.write(tmp_path / "a.npz", points)
    back = pio.read(tmp_path / "a.npz")
    np.testing.assert_array_equal(back.points, points)
    assert back.normals is None
    part = datasets.cad_part(n_points=1500, noise=0.004, seed=0).points
    result = pssd_fast.denoise(part, preset="fast")
    pio.write(tmp_path / "b.npz", result)
    back = pio.read(tmp_path / "b.npz")
    np.testing.assert_array_equal(back.points, result.points)
    np.testing.assert_array_equal(back.normals, result.normals)


@pytest.mark.parametrize("cloud, match", [
    ({"points": np.zeros((4, 3))}, "got dict$"),
    (np.zeros((4, 2)), r"got ndarray of shape \(4, 2\), dtype float64$"),
    ("a.ply", "got str$"),
])
def test_write_refuses_what_is_not_a_cloud(tmp_path, cloud, match):
    with pytest.raises(TypeError, match="^cloud must be a pssd_fast.io.PointCloud, a denoise "
                                        "result or an \\(n, 3\\) array of coordinates; " + match):
        pio.write(tmp_path / "a.ply", cloud)
    assert list(tmp_path.iterdir()) == []


def test_describe_says_nothing_where_the_format_has_nothing_more(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((4, 3)))
    assert pio.describe(pio.read(tmp_path / "a.npy")) == []
    assert pio.describe(PointCloud(np.zeros((4, 3)), format="ply")) == []


def test_a_compressed_las_1_2_file_reads_after_its_header_checks(tmp_path):
    """The LAZ chunk checks read beyond the header: laspy must start from byte 0 anyway (a
    LAS 1.2 file has no EVLRs to check after them)."""
    laspy = pytest.importorskip("laspy")
    pytest.importorskip("lazrs")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    xyz = np.random.default_rng(0).random((500, 3)) * 10
    las.x, las.y, las.z = xyz.T
    path = tmp_path / "v12.laz"
    las.write(path)
    cloud = pio.read(path)
    assert cloud.points.shape == (500, 3)
    assert np.allclose(cloud.points, xyz, atol=0.006)
