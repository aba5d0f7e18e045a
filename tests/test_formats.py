"""pssd_fast.io formats: CSV and headers, integer columns, PTS, OBJ, gzip and
stdin/stdout."""
import contextlib
import gzip
import io
import warnings

import numpy as np
import pytest

from pssd_fast import io as pio
from pssd_fast.io import PointCloud, PointCloudFileError

from .conftest import laspy, needs_laspy, needs_plyfile, plyfile

RNG = np.random.default_rng(7)
PTS = RNG.normal(size=(5, 3)) * 100
RGB = RNG.integers(0, 256, (5, 3))
NRM = RNG.normal(size=(5, 3))


def rows(*columns, sep=" "):
    """Text rows of the given columns: floats by repr, integers as integers."""
    table = np.column_stack(columns).astype(object)
    kinds = [c.dtype.kind for c in columns for _ in range(1 if c.ndim == 1 else c.shape[1])]
    return [sep.join(str(int(v)) if k in "iu" else repr(float(v)) for v, k in zip(row, kinds))
            for row in table]


def write_text(path, lines):
    path.write_text("\n".join(lines) + "\n")
    return path


# ---------------------------------------------------------------------------------------------
# Separators, headers and names


@pytest.mark.parametrize("sep", [",", ";", "\t", " ", ", "])
@pytest.mark.parametrize("header", ["//X{s}Y{s}Z{s}R{s}G{s}B", "x{s}y{s}z{s}red{s}green{s}blue",
                                    "# X Y Z r g b", "//X Y Z Red Green Blue", None])
def test_separators_and_header_variants(tmp_path, sep, header):
    lines = rows(PTS, RGB, sep=sep)
    if header is not None:
        lines.insert(0, header.format(s=sep.strip() or sep))
    # Without names, three integer columns after x y z are colours, and a note says so.
    with (pytest.warns(pio.PointCloudWarning, match=r"columns 4-6 read as red, green, blue "
                                                    r"\(integers\)")
          if header is None else contextlib.nullcontext()):
        cloud = pio.read(write_text(tmp_path / "a.txt", lines))
    np.testing.assert_array_equal(cloud.points, PTS)
    names = ["red", "green", "blue"]
    assert cloud.normals is None
    assert list(cloud.fields) == names
    for i, name in enumerate(names):
        assert cloud.fields[name].dtype == np.uint8
        np.testing.assert_array_equal(cloud.fields[name], RGB[:, i])


@pytest.mark.parametrize("header, expected", [
    ("X,Y,Z,Nx,Ny,Nz,Intensity,scalar_Classification,Scalar field",
     ["intensity", "classification", "Scalar_field"]),
    ("x,y,z,normal_x,normal_y,normal_z,i,scalar_intensity2,a",
     ["intensity", "scalar_intensity2", "alpha"]),
    # Units after known names are dropped; after other names they stay part of the name.
    ("x [m],Y (m),z[m],nx,ny,nz,Intensity [dB],temp (C),a",
     ["intensity", "temp_(C)", "alpha"]),
])
def test_names_are_mapped_case_insensitively(tmp_path, header, expected):
    extra = RNG.integers(0, 9, (5, 3))
    cloud = pio.read(write_text(tmp_path / "a.csv", [header, *rows(PTS, NRM, extra, sep=",")]))
    np.testing.assert_array_equal(cloud.points, PTS)
    np.testing.assert_array_equal(cloud.normals, NRM)
    assert list(cloud.fields) == expected


def test_named_columns_may_come_in_any_order(tmp_path):
    lines = ["id;Z;Y;X", *rows(np.arange(5), PTS[:, 2], PTS[:, 1], PTS[:, 0], sep=";")]
    cloud = pio.read(write_text(tmp_path / "a.csv", lines))
    np.testing.assert_array_equal(cloud.points, PTS)
    np.testing.assert_array_equal(cloud.fields["id"], np.arange(5))


@pytest.mark.parametrize("header, match", [
    ("x y z r g", r"header line 1 names 5 columns but the data has 6"),
    ("a b c d e f", r"header line 1 names no x, y and z columns"),
    ("x y z r red g", r"header line 1 names columns \['red'\] more than once"),
])
def test_bad_header_lines(tmp_path, header, match):
    with pytest.raises(PointCloudFileError, match=match):
        pio.read(write_text(tmp_path / "a.xyz", [header, *rows(PTS, RGB)]))


def test_a_csv_header_with_an_empty_name_is_refused(tmp_path):
    """Found by the readers' fuzz: an empty name between two commas."""
    path = write_text(tmp_path / "a.csv", ["x,y,z,,green,blue", *rows(PTS, RGB, sep=",")])
    with pytest.raises(PointCloudFileError, match="header line 1 leaves column 4 without a name"):
        pio.read(path)


def test_a_comment_that_names_nothing_stays_a_comment(tmp_path):
    path = write_text(tmp_path / "a.xyz", ["# scanned on monday", *rows(PTS)])
    cloud = pio.read(path)
    pio.write(tmp_path / "b.xyz", cloud)
    assert (tmp_path / "b.xyz").read_text().splitlines()[:2] == ["# scanned on monday",
                                                                "# x y z"]


def test_csv_round_trip_keeps_integers_and_floats(tmp_path):
    labels = np.array([3, -2, 70000, 0, 1])
    quality = np.array([1.0, 2.0, 0.5, 4.0, 5.0])  # a float column, some values whole
    whole = np.array([1.0, 2.0, 3.0, 4.0, 5.0])  # whole numbers written as floats: stays float
    lines = ["x,y,z,red,green,blue,label,quality,whole",
             *rows(PTS, RGB, labels, quality, whole, sep=",")]
    cloud = pio.read(write_text(tmp_path / "a.csv", lines))
    assert cloud.fields["label"].dtype == np.int32
    assert cloud.fields["quality"].dtype == np.float64
    assert cloud.fields["whole"].dtype == np.float64
    pio.write(tmp_path / "b.csv", cloud)
    out = (tmp_path / "b.csv").read_text().splitlines()
    assert out[0] == "x,y,z,red,green,blue,label,quality,whole"
    assert out[1].split(",")[3:] == [*map(str, RGB[0]), "3", "1.0", "1.0"]
    back = pio.read(tmp_path / "b.csv")
    for name, values in cloud.fields.items():
        assert back.fields[name].dtype == values.dtype
        np.testing.assert_array_equal(back.fields[name], values)


def test_sixteen_bit_colours_and_big_integers(tmp_path):
    big = np.array([2**40, 1, 2, 3, 4])
    lines = ["x y z red green blue id", *rows(PTS, RGB * 257, big)]
    cloud = pio.read(write_text(tmp_path / "a.xyz", lines))
    assert cloud.fields["red"].dtype == np.uint16
    assert cloud.fields["id"].dtype == np.int64
    np.testing.assert_array_equal(cloud.fields["id"], big)


# ---------------------------------------------------------------------------------------------
# Six unnamed columns, and names given


UNIT = NRM / np.linalg.norm(NRM, axis=1, keepdims=True)


@pytest.mark.parametrize("columns, expected, why", [
    # The line, and a black point: integers are colours, written back as integers.
    (np.array([[96, 133, 142], [0, 0, 0], [255, 255, 255], [1, 2, 3], [0, 0, 1]]),
     ["red", "green", "blue"], "integers"),
    (UNIT, ["nx", "ny", "nz"], "unit vectors"),
    # Within 5% of unit length (two decimals), or no normal at all (NaN, zeros).
    (np.vstack([np.round(UNIT[:3], 2), [np.nan] * 3, [0.0] * 3]), ["nx", "ny", "nz"],
     "unit vectors"),
    # Integers that no colour has (negative) but unit length: normals.
    (np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, 0, 0]]),
     ["nx", "ny", "nz"], "unit vectors"),
    # Float colours in [0, 1] and other floats: plain fields, kept as read.
    (np.array([[0.5, 0.2, 0.1], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.3, 0.3, 0.3],
               [0.9, 0.1, 0.1]]), ["col3", "col4", "col5"], "neither"),
    (UNIT * 1.2, ["col3", "col4", "col5"], "neither"),
])
def test_six_unnamed_columns(tmp_path, columns, expected, why):
    path = write_text(tmp_path / "a.xyz", rows(PTS, columns))
    with pytest.warns(pio.PointCloudWarning, match=rf"a\.xyz: no column names; columns 4-6 "
                                                   rf"read as {', '.join(expected)} \({why}"):
        cloud = pio.read(path)
    np.testing.assert_array_equal(cloud.points, PTS)
    if expected[0] == "nx":
        np.testing.assert_array_equal(cloud.normals, columns)
        assert cloud.fields == {}
        return
    assert cloud.normals is None and list(cloud.fields) == expected
    for i, name in enumerate(expected):
        np.testing.assert_array_equal(cloud.fields[name], columns[:, i])
    if why == "integers":
        assert cloud.fields["red"].dtype == np.uint8
        pio.write(tmp_path / "b.xyz", cloud)
        out = (tmp_path / "b.xyz").read_text().splitlines()
        assert out[0] == "# x y z red green blue"
        assert [line.split()[3:] for line in out[1:]] == [r.split()[3:] for r in rows(PTS,
                                                                                     columns)]


def test_columns_name_the_columns(tmp_path):
    """Names given read a file without names without a note, win over a header line (with a
    note where they differ), and are checked like a header line."""
    lines = rows(PTS, RGB)
    path = write_text(tmp_path / "a.xyz", lines)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cloud = pio.read(path, columns="X,Y,Z,r,g,b")
        same = pio.read(write_text(tmp_path / "h.xyz", ["# x y z red green blue", *lines]),
                        columns=["x", "y", "z", "red", "green", "blue"])
    for read in (cloud, same):
        assert read.normals is None and list(read.fields) == ["red", "green", "blue"]
        np.testing.assert_array_equal(read.fields["green"], RGB[:, 1])
    wrong = write_text(tmp_path / "b.csv", ["x,y,z,nx,ny,nz", *rows(PTS, RGB, sep=",")])
    with pytest.warns(pio.PointCloudWarning, match=r"b\.csv: the column names given \(x, y, z, "
                                                   r"red, green, blue\) replace those of header "
                                                   r"line 1 \(x, y, z, nx, ny, nz\)"):
        fixed = pio.read(wrong, columns="x,y,z,red,green,blue")
    assert fixed.normals is None and fixed.fields["red"].dtype == np.uint8
    pio.write(tmp_path / "c.csv", fixed)
    assert (tmp_path / "c.csv").read_text().splitlines()[0] == "x,y,z,red,green,blue"
    # A bare header line that names nothing is replaced, not refused.
    odd = write_text(tmp_path / "d.xyz", ["a b c d e f", *lines])
    with pytest.warns(pio.PointCloudWarning, match="replace those of header line 1 "
                                                   r"\(a b c d e f\)"):
        assert list(pio.read(odd, columns="x,y,z,i,j,k").fields) == ["intensity", "j", "k"]
    for columns, error, match in (
            ("x,y,z", PointCloudFileError, "the column list x,y,z names 3 columns but the data "
                                           "has 6"),
            ("x,y,z,r,r,g", PointCloudFileError, r"names columns \['red'\] more than once"),
            ("a,b,c,d,e,f", PointCloudFileError, "names no x, y and z columns"),
            (3, TypeError, "comma-separated string or a sequence of strings"),
            (["x", "y", 3], TypeError, "sequence of strings")):
        with pytest.raises(error, match=match):
            pio.read(path, columns=columns)
    np.save(tmp_path / "e.npy", PTS)
    with pytest.raises(PointCloudFileError, match=r"e\.npy: columns= names the columns of text "
                                                  r"files"):
        pio.read(tmp_path / "e.npy", columns="x,y,z")


# ---------------------------------------------------------------------------------------------
# PTS


def test_pts_reads_intensity_and_rgb(tmp_path):
    intensity = np.array([-2048, 0, 5, 2047, 12])
    path = write_text(tmp_path / "a.pts", ["5", *rows(PTS, intensity, RGB)])
    cloud = pio.read(path)
    assert list(cloud.fields) == ["intensity", "red", "green", "blue"]
    assert cloud.fields["intensity"].dtype == np.int32
    assert cloud.fields["red"].dtype == np.uint8
    np.testing.assert_array_equal(cloud.fields["intensity"], intensity)
    four = pio.read(write_text(tmp_path / "b.pts", ["5", *rows(PTS, intensity)]))
    assert list(four.fields) == ["intensity"]


def test_pts_output_puts_leica_columns_first(tmp_path):
    intensity = np.arange(5)
    cloud = PointCloud(PTS, None, {"green": RGB[:, 1].astype(np.uint8), "intensity": intensity,
                                   "red": RGB[:, 0].astype(np.uint8),
                                   "blue": RGB[:, 2].astype(np.uint8)})
    pio.write(tmp_path / "a.pts", cloud)
    lines = (tmp_path / "a.pts").read_text().splitlines()
    assert lines[0] == "5"  # strict Leica PTS: no column line needed
    assert lines[1].split()[3:] == ["0", *map(str, RGB[0])]


# ---------------------------------------------------------------------------------------------
# OBJ


OBJ = """# made by a mesher
mtllib part.mtl
o part
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
vt 0.5 0.5
vn 0 0 1
vn 0 0 1
vn 0 0 1
vn 1 0 0
usemtl steel
f 1//1 2//2 3//3
f 1 3 4
"""


def test_obj_round_trip_keeps_every_other_line(tmp_path):
    (tmp_path / "a.obj").write_text(OBJ)
    cloud = pio.read(tmp_path / "a.obj")
    assert cloud.format == "obj"
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(cloud.normals[3], [1, 0, 0])
    moved = cloud.points + 0.25
    pio.write(tmp_path / "b.obj", cloud, points=moved, normals=-cloud.normals)
    out = (tmp_path / "b.obj").read_text().splitlines()
    kept = [line for line in OBJ.splitlines() if not line.startswith(("v ", "vn "))]
    assert [line for line in out if not line.startswith(("v ", "vn "))] == kept
    assert out[3] == "v 0.25 0.25 0.25" and out[8] == "vn -0.0 -0.0 -1.0"
    back = pio.read(tmp_path / "b.obj")
    np.testing.assert_array_equal(back.points, moved)
    np.testing.assert_array_equal(back.normals, -cloud.normals)


def test_obj_gets_normals_after_its_vertices_and_keeps_colours(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0 1 0.5 0\nv 1 0 0 0 0 1\nv 0 1 0 1 1 1\nf 1 2 3\n")
    cloud = pio.read(tmp_path / "a.obj")
    assert cloud.normals is None
    np.testing.assert_array_equal(cloud.fields["green"], [0.5, 0, 1])
    with pytest.warns(pio.PointCloudWarning, match=r"\.obj cannot hold fields \['likelihood'\]"):
        pio.write(tmp_path / "b.obj", cloud, normals=np.eye(3), fields={"likelihood": np.ones(3)})
    assert (tmp_path / "b.obj").read_text().splitlines() == [
        "v 0.0 0.0 0.0 1.0 0.5 0.0", "v 1.0 0.0 0.0 0.0 0.0 1.0", "v 0.0 1.0 0.0 1.0 1.0 1.0",
        "vn 1.0 0.0 0.0", "vn 0.0 1.0 0.0", "vn 0.0 0.0 1.0", "f 1 2 3"]


@pytest.mark.parametrize("dtype, values, scale", [(np.uint8, [0, 128, 255], 255.0),
                                                  (np.uint16, [0, 300, 65535], 65535.0),
                                                  (np.uint16, [0, 20, 255], 255.0)])
def test_obj_colours_are_written_as_unit_floats(tmp_path, dtype, values, scale):
    """Integer colours (a PLY's or a LAS file's) go to OBJ as MeshLab, Open3D and trimesh read
    them: 0-1 floats, 8 bits or 16 (above 255); the renderer takes them back alike."""
    from pssd_fast.pictures.colours import rgb_colours
    colours = {name: np.array(values, dtype) for name in ("red", "green", "blue")}
    pio.write(tmp_path / "a.obj", PointCloud(PTS[:3], None, colours))
    lines = (tmp_path / "a.obj").read_text().splitlines()
    assert [float(line.split()[4]) for line in lines] == [v / scale for v in values]
    back = pio.read(tmp_path / "a.obj").fields
    np.testing.assert_array_equal(rgb_colours(back["red"], back["green"], back["blue"]),
                                  rgb_colours(*colours.values()))


def test_obj_elements_are_described(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 3 2 1\nl 1 2\n")
    assert pio.describe(pio.read(tmp_path / "a.obj")) == [
        "other elements: faces (2), lines (1)"]
    (tmp_path / "b.obj").write_text("v 0 0 0\nv 1 0 0\n")
    assert pio.describe(pio.read(tmp_path / "b.obj")) == ["other elements: none"]


def test_obj_errors(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0\n")
    with pytest.raises(PointCloudFileError, match=r"a\.obj: line 2: malformed v line 'v 1 0'"):
        pio.read(tmp_path / "a.obj")
    (tmp_path / "b.obj").write_text("v 0 0\n")
    with pytest.raises(PointCloudFileError, match=r"line 1: a v line holds 3 or 4 or 6"):
        pio.read(tmp_path / "b.obj")
    (tmp_path / "c.obj").write_text("f 1 2 3\n")
    with pytest.raises(PointCloudFileError, match=r"c\.obj: holds no points"):
        pio.read(tmp_path / "c.obj")


# ---------------------------------------------------------------------------------------------
# gzip


@pytest.mark.parametrize("ext", [".xyz.gz", ".csv.gz", ".obj.gz",
                                 pytest.param(".ply.gz", marks=needs_plyfile)])
def test_gzip_round_trip(tmp_path, ext):
    colours = {name: RGB[:, i].astype(np.uint8) for i, name in enumerate(("red", "green",
                                                                          "blue"))}
    cloud = PointCloud(PTS, NRM, colours)
    pio.write(tmp_path / f"a{ext}", cloud)
    raw = (tmp_path / f"a{ext}").read_bytes()
    assert raw[:2] == b"\x1f\x8b"
    back = pio.read(tmp_path / f"a{ext}")
    np.testing.assert_array_equal(back.points, PTS)
    np.testing.assert_array_equal(back.normals, NRM)
    if ext == ".obj.gz":  # OBJ colours are 0-1 floats
        np.testing.assert_array_equal(back.fields["red"], RGB[:, 0] / 255.0)
    else:
        np.testing.assert_array_equal(back.fields["red"], RGB[:, 0])
        assert back.fields["red"].dtype == np.uint8
    # Same data, same bytes: no name (flags byte 0) and no time stamp in the gzip header.
    assert raw[3] == 0 and raw[4:8] == b"\0\0\0\0"


def test_gzip_errors(tmp_path):
    (tmp_path / "a.xyz.gz").write_bytes(gzip.compress(b"1 2 3\n")[:-6])
    with pytest.raises(PointCloudFileError, match=r"a\.xyz\.gz: not a complete gzip file"):
        pio.read(tmp_path / "a.xyz.gz")
    with pytest.raises(PointCloudFileError, match=r"\.npz files cannot be gzipped"):
        pio.write(tmp_path / "a.npz.gz", PointCloud(PTS))
    with pytest.raises(PointCloudFileError, match=r"unknown extension '\.e57\.gz'"):
        pio.read(tmp_path / "a.e57.gz")


# ---------------------------------------------------------------------------------------------
# stdin and stdout


class Stdio:
    """Stands for sys.stdin / sys.stdout: only the binary buffer is used."""

    def __init__(self, data=b""):
        self.buffer = io.BytesIO(data)


def test_stdin_and_stdout(monkeypatch):
    monkeypatch.setattr("sys.stdin", Stdio("\n".join(rows(PTS, NRM, sep=",")).encode()))
    with pytest.warns(pio.PointCloudWarning, match="<stdin>: no column names; columns 4-6 "
                                                   "read as col3, col4, col5"):
        cloud = pio.read("-", format="csv")
    np.testing.assert_array_equal(cloud.points, PTS)
    assert cloud.source.path is None
    out = Stdio()
    monkeypatch.setattr("sys.stdout", out)
    assert pio.write("-", cloud, format=".xyz.gz") == "-"
    text = gzip.decompress(out.buffer.getvalue()).decode()
    assert text.splitlines()[0] == "# x y z col3 col4 col5"
    with pytest.raises(PointCloudFileError, match=r"<stdin>: reading or writing '-' needs a "
                                                  r"format"):
        pio.read("-")
    with pytest.raises(PointCloudFileError, match=r"<stdout>: unknown format 'e57'"):
        pio.write("-", cloud, format="e57")


# ---------------------------------------------------------------------------------------------
# Output types


def test_npy_holds_points_only(tmp_path):
    with pytest.warns(pio.PointCloudWarning, match="cannot hold normals"):
        pio.write(tmp_path / "a.npy", PointCloud(PTS, NRM))
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), PTS)


@needs_plyfile
def test_text_colours_become_uchar_ply_properties(tmp_path):
    path = write_text(tmp_path / "a.xyz", ["X Y Z R G B", *rows(PTS, RGB)])
    pio.write(tmp_path / "b.ply", pio.read(path), fields={"likelihood": np.ones(5, np.float32)})
    props = {p.name: p.val_dtype for p in plyfile.PlyData.read(tmp_path / "b.ply")["vertex"]
             .properties}
    assert props == {"x": "f8", "y": "f8", "z": "f8", "red": "u1", "green": "u1", "blue": "u1",
                     "likelihood": "f4"}


@needs_laspy
def test_new_las_normals_are_float32(tmp_path):
    pio.write(tmp_path / "a.las", PointCloud(PTS, NRM))
    las = laspy.read(tmp_path / "a.las")
    assert {name: las[name].dtype for name in ("nx", "ny", "nz")} == {
        "nx": np.float32, "ny": np.float32, "nz": np.float32}


def test_selected_rows_of_an_obj_without_faces_are_written(tmp_path):
    from pssd_fast import io as pio
    path = tmp_path / "pts.obj"
    path.write_text("# points\nv 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\n")
    cloud = pio.select(pio.read(path), [0, 2, 3])
    pio.write(tmp_path / "out.obj", cloud)
    lines = (tmp_path / "out.obj").read_text().splitlines()
    assert lines[0] == "# points" and [float(line.split()[1]) for line in lines[1:]] == [0, 2, 3]


def test_selecting_rows_of_an_obj_with_faces_is_refused(tmp_path):
    from pssd_fast import io as pio
    path = tmp_path / "mesh.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\n")
    with pytest.raises(pio.PointCloudFileError, match="faces"):
        pio.select(pio.read(path), [0, 1, 2])
