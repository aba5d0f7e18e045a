"""Mesh I/O, surface sampling, sharp-edge detection and exact segment distances."""
import gzip
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from pykdtree.kdtree import KDTree

from benchmarks import meshes, models

from .conftest import data_file

pytestmark = pytest.mark.tooling


def cube_mesh():
    """Unit cube with 2 outward-wound triangles per face: 8 vertices, 12 faces, 18 edges."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return v, faces


# -- read_obj -------------------------------------------------------------------------------------

TINY_OBJ = """\
# a square, a triangle given twice (relative indices), a fan
v 0 0 0
v 1 0 0
v 1 1 0 1.0
v 0 1 0   # trailing comment
vt 0 0
vn 0 0 1
f 1/1 2/1/1 3//1 4
  f -4 -3 -2
v 2 2 2
usemtl steel
f 1 5 -1
f 1 2 3 4 5
"""


@pytest.mark.parametrize("compress", [False, True])
def test_read_obj_forms(tmp_path, compress):
    path = tmp_path / ("tiny.obj.gz" if compress else "tiny.obj")
    with (gzip.open if compress else open)(path, "wt") as fh:
        fh.write(TINY_OBJ)
    vertices, faces = meshes.read_obj(path)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    assert np.array_equal(vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 2, 2]])
    assert np.array_equal(faces, [[0, 1, 2], [0, 2, 3],  # quad, fanned
                                  [0, 1, 2],              # -4 -3 -2 with 4 vertices so far
                                  [0, 4, 4],              # -1 is now vertex 5
                                  [0, 1, 2], [0, 2, 3], [0, 3, 4]])


def test_read_obj_crlf_and_vertices_only(tmp_path):
    path = tmp_path / "crlf.obj"
    path.write_bytes(b"v 0 0 0\r\nv 1 2 3\r\n")
    vertices, faces = meshes.read_obj(str(path))
    assert np.array_equal(vertices, [[0, 0, 0], [1, 2, 3]])
    assert faces.shape == (0, 3)


@pytest.mark.parametrize("text, lineno", [
    ("v 0 0 0\nv 1 1\n", 2),                                 # too few coordinates
    ("v 0 0 0\nv 1 x 1\n", 2),                               # not a number
    ("v 0 0 0\n\nv 1 nan 1\n", 3),                           # not finite
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4),               # too few corners
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 a\n", 5),    # bad index
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 0 1 2\n", 5),    # 0 is not an OBJ index
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4),             # past the last vertex
    ("v 0 0 0\nv 1 0 0\nf -3 1 2\nv 0 1 0\n", 3),            # before the first vertex
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\nf 1 2 3 9\n", 6),
])
def test_read_obj_malformed_names_the_line(tmp_path, text, lineno):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"bad.obj:{lineno}:"):
        meshes.read_obj(path)


def test_read_obj_reference_meshes():
    vertices, faces = meshes.read_obj(data_file("meshes", "fandisk.obj.gz"))
    assert vertices.shape == (6475, 3) and faces.shape == (12946, 3)
    assert np.linalg.norm(np.ptp(vertices, axis=0)) == pytest.approx(7.615589, abs=1e-6)
    vertices, faces = meshes.read_obj(data_file("meshes", "igea.obj.gz"))
    assert vertices.shape == (134345, 3) and faces.shape == (268686, 3)
    assert faces.min() == 0 and faces.max() == 134344


# -- read_feat ------------------------------------------------------------------------------------


def test_read_feat_tiny(tmp_path):
    path = tmp_path / "tiny.feat"
    path.write_text("feat 2\n2\n0 0 0\n1 0 0\n\n3\n0 0 1\n0 1 1\n1.5 1 1\n")
    lines = meshes.read_feat(path)
    assert len(lines) == 2
    assert np.array_equal(lines[0], [[0, 0, 0], [1, 0, 0]])
    assert np.array_equal(lines[1], [[0, 0, 1], [0, 1, 1], [1.5, 1, 1]])
    assert lines[1].dtype == np.float64


@pytest.mark.parametrize("text, match", [
    ("", "empty"),
    ("feet 1\n1\n0 0 0\n", ":1:"),
    ("feat 1\n2\n0 0 0\n1 1 1 1\n", ":4:"),
    ("feat 1\n2\n0 0 0\n1 x 1\n", ":4:"),
    ("feat x\n", ":1:"),
    ("feat -2\n", ":1:"),
    ("feat 1\n3\n0 0 0\n", ":2:"),
    ("feat 2\n1\n0 0 0\n", "1 of 2"),
    ("feat 1\n1\n0 0 0\n5\n", ":4:"),
    ("feat 1\n-1\n", ":2:"),
])
def test_read_feat_malformed(tmp_path, text, match):
    path = tmp_path / "bad.feat"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        meshes.read_feat(path)


def test_fandisk_feature_curves_are_its_sharp_edges():
    vertices, faces = meshes.read_obj(data_file("meshes", "fandisk.obj.gz"))
    curves = meshes.read_feat(data_file("meshes", "fandisk.feat.gz"))
    assert len(curves) == 35 and sum(len(c) for c in curves) == 757
    edges = meshes.sharp_edges(vertices, faces, 30.0)
    assert edges.shape == (722, 2)
    # Snapped to the nearest vertex, the polylines are exactly the sharp edges (as the
    # SOURCES.md of the mesh folder states).
    tree = KDTree(vertices)
    snapped = set()
    for curve in curves:
        _, idx = tree.query(curve, k=1)
        snapped.update((min(i, j), max(i, j)) for i, j in zip(idx[:-1].tolist(), idx[1:].tolist()))
    assert snapped == set(map(tuple, edges.tolist()))


# -- sample_surface -------------------------------------------------------------------------------


def two_triangles():
    """Triangles of area 0.5 and 1.5 in the z = 0 plane, wound to face +z and -z."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0], [5, 0, 0]], float)
    return v, np.array([[0, 1, 2], [3, 4, 5]])


def test_sample_surface_area_uniform():
    v, f = two_triangles()
    n = 40_000
    points, face_index, normals = meshes.sample_surface(v, f, n, seed=3)
    assert points.shape == (n, 3) and normals.shape == (n, 3) and face_index.shape == (n,)
    assert face_index.dtype == np.int64
    share = np.mean(face_index == 0)
    assert abs(share - 0.25) < 5 * np.sqrt(0.25 * 0.75 / n)
    # Inside their triangle (barycentric coordinates in [0, 1]).
    for k, (a, b, c) in enumerate(v[f]):
        p = points[face_index == k] - a
        uv = np.linalg.solve(np.column_stack([b - a, c - a])[:2], p[:, :2].T).T
        assert np.all(uv >= -1e-12) and np.all(uv.sum(axis=1) <= 1 + 1e-12)
        # Uniform within: the half-size corner triangle at a holds a quarter of the points
        # (without the sqrt trick it would hold a half).
        inner = uv.sum(axis=1) < 0.5
        assert abs(inner.mean() - 0.25) < 5 * np.sqrt(0.25 * 0.75 / len(p))
    assert np.allclose(normals[face_index == 0], [0, 0, 1])
    assert np.allclose(normals[face_index == 1], [0, 0, -1])


def test_sample_surface_reproducible_and_shuffled():
    v, f = cube_mesh()
    a = meshes.sample_surface(v, f, 5000, seed=1)
    b = meshes.sample_surface(v, f, 5000, seed=1)
    c = meshes.sample_surface(v, f, 5000, seed=2)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert not np.array_equal(a[0], c[0])
    assert np.any(np.diff(a[1]) < 0)  # not grouped by face
    # Cube normals are the outward face normals.
    centre = np.array([0.5, 0.5, 0.5])
    assert np.all(np.einsum("ij,ij->i", a[2], a[0] - centre) > 0)
    assert np.allclose(np.abs(a[2]).max(axis=1), 1.0)


def test_sample_surface_skips_degenerate_faces():
    v, f = two_triangles()
    f = np.vstack([f, [[0, 1, 3]]])  # collinear: zero area
    _, face_index, normals = meshes.sample_surface(v, f, 2000)
    assert not np.any(face_index == 2) and np.isfinite(normals).all()


@pytest.mark.parametrize("args, error, match", [
    ((0,), ValueError, "n_points"),
    ((2.5,), TypeError, "n_points"),
    ((10, -1), ValueError, "seed"),
])
def test_sample_surface_bad_arguments(args, error, match):
    v, f = two_triangles()
    with pytest.raises(error, match=match):
        meshes.sample_surface(v, f, *args)


def test_sample_surface_bad_meshes():
    v, f = two_triangles()
    with pytest.raises(ValueError, match="6 vertices"):
        meshes.sample_surface(v, f + 1, 10)
    with pytest.raises(TypeError, match="integer"):
        meshes.sample_surface(v, f.astype(float), 10)
    with pytest.raises(ValueError, match="shape"):
        meshes.sample_surface(v[:, :2], f, 10)
    with pytest.raises(ValueError, match="zero total area"):
        meshes.sample_surface(np.zeros((3, 3)), [[0, 1, 2]], 10)


# -- sharp_edges ----------------------------------------------------------------------------------


def test_sharp_edges_cube():
    v, f = cube_mesh()
    edges = meshes.sharp_edges(v, f)
    assert edges.shape == (12, 2) and edges.dtype == np.int64
    assert np.all(edges[:, 0] < edges[:, 1])
    assert np.array_equal(edges, np.unique(edges, axis=0))  # sorted, no repeats
    # The 12 cube edges join vertices differing in one coordinate; the 6 face diagonals
    # (also mesh edges, between coplanar triangles) are not sharp.
    assert np.all(np.sum(v[edges[:, 0]] != v[edges[:, 1]], axis=1) == 1)
    assert len(meshes.sharp_edges(v, f, angle_deg=89.0)) == 12
    assert len(meshes.sharp_edges(v, f, angle_deg=91.0)) == 0
    # Turned the other way round (all normals inward) the angles are the same.
    assert np.array_equal(meshes.sharp_edges(v, f[:, ::-1]), edges)


def test_sharp_edges_boundary_and_flip():
    # Two triangles folded by 90 degrees along the edge (0, 1): the other 4 edges are boundary.
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 0, 1]], float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    assert np.array_equal(meshes.sharp_edges(v, f), [[0, 1]])
    # Flattened to 20 degrees of bend: not sharp at 30, sharp at 10.
    bend = np.radians(20)
    v[3] = [0.5, -np.cos(bend), np.sin(bend)]
    assert len(meshes.sharp_edges(v, f, 30.0)) == 0
    assert np.array_equal(meshes.sharp_edges(v, f, 10.0), [[0, 1]])
    # A single face has only boundary edges.
    assert meshes.sharp_edges(v, f[:1]).shape == (0, 2)
    # Next to a zero-area face the angle is undefined: not reported, and no warning.
    flat = np.array([[0, 1, 2], [1, 0, 1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert meshes.sharp_edges(v, flat, 10.0).shape == (0, 2)
    # A third face on the edge (0, 1) makes it non-manifold: not a two-face edge, not reported.
    v = np.vstack([v, [[0.5, 0, -1]]])
    assert meshes.sharp_edges(v, np.vstack([f, [[0, 1, 4]]]), 10.0).shape == (0, 2)


def test_sharp_edges_bad_angle():
    v, f = cube_mesh()
    with pytest.raises(ValueError, match="200"):
        meshes.sharp_edges(v, f, 200)
    with pytest.raises(TypeError, match="angle_deg"):
        meshes.sharp_edges(v, f, "30")


# -- segment_distance -----------------------------------------------------------------------------


def brute_segment_distance(points, a, b):
    best = np.full(len(points), np.inf)
    for p0, p1 in zip(a, b):
        d = p1 - p0
        dd = d @ d
        t = np.zeros(len(points)) if dd == 0 else np.clip((points - p0) @ d / dd, 0, 1)
        best = np.minimum(best, np.linalg.norm(points - p0 - t[:, None] * d, axis=1))
    return best


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(11)
    a = rng.normal(size=(300, 3))
    b = a + rng.normal(scale=0.3, size=(300, 3))
    b[:5] = a[:5]  # zero-length segments are points
    points = rng.normal(size=(5000, 3))  # several chunks
    points[:20] = a[20:40] + 0.3 * (b[20:40] - a[20:40])  # exactly on segments
    got = meshes.segment_distance(points, a, b)
    assert got.shape == (5000,)
    assert np.allclose(got, brute_segment_distance(points, a, b), rtol=1e-12, atol=1e-15)
    assert np.all(got[:20] < 1e-15)


def test_segment_distance_hand_values_and_precision():
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[1.0, 0.0, 0.0]])
    q = np.array([[0.5, 3.0, 4.0], [-3.0, 4.0, 0.0], [4.0, 0.0, 4.0], [0.25, 0.0, 0.0]])
    assert np.allclose(meshes.segment_distance(q, a, b), [5.0, 5.0, 5.0, 0.0], rtol=0, atol=1e-15)
    # Far from the origin the distance keeps full precision (no |p|^2 expansion).
    offset = np.array([1e4, -2e4, 3e4])
    tiny = meshes.segment_distance(offset + [[0.5, 1e-9, 0.0]], a + offset, b + offset)
    assert tiny[0] == pytest.approx(1e-9, rel=1e-3)


def test_segment_distance_bad_inputs():
    a = np.zeros((3, 3))
    with pytest.raises(ValueError, match="same shape"):
        meshes.segment_distance(np.zeros((2, 3)), a, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="empty"):
        meshes.segment_distance(np.zeros((2, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="shape"):
        meshes.segment_distance(np.zeros((2, 2)), a, a)
    assert meshes.segment_distance(np.zeros((0, 3)), a, a).shape == (0,)


# -- normalisation and the data directory ---------------------------------------------------------


def test_normalize_to_unit_diagonal():
    rng = np.random.default_rng(0)
    v = rng.uniform([-3, 10, 0], [5, 11, 0.5], size=(500, 3))
    scaled, scale, offset = meshes.normalize_to_unit_diagonal(v)
    lo, hi = scaled.min(axis=0), scaled.max(axis=0)
    assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(lo + hi, 0.0, atol=1e-12)
    assert np.allclose(scaled / scale + offset, v, atol=1e-12)
    with pytest.raises(ValueError, match="diagonal"):
        meshes.normalize_to_unit_diagonal(np.ones((4, 3)))
    with pytest.raises(ValueError, match="empty"):
        meshes.normalize_to_unit_diagonal(np.zeros((0, 3)))


def test_data_dir_from_pssd_data(monkeypatch, tmp_path):
    (tmp_path / "meshes").mkdir()
    monkeypatch.setenv("PSSD_DATA", str(tmp_path))
    assert meshes.data_dir() == tmp_path / "meshes"
    # A setting that points nowhere is reported, not replaced by another folder.
    monkeypatch.setenv("PSSD_DATA", str(tmp_path / "missing"))
    assert meshes.data_dir() is None
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("PSSD_DATA", str(tmp_path / "file"))
    assert meshes.data_dir() is None


def test_data_dir_from_argument(monkeypatch, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "meshes").mkdir(parents=True)
    (tmp_path / "meshes").mkdir()
    monkeypatch.setenv("PSSD_DATA", str(elsewhere))
    assert meshes.data_dir(tmp_path) == tmp_path / "meshes"  # the argument wins over PSSD_DATA
    assert meshes.data_dir(str(tmp_path)) == tmp_path / "meshes"
    assert meshes.data_dir(tmp_path / "missing") is None
    monkeypatch.setenv("HOME", str(tmp_path))
    assert meshes.data_dir("~/elsewhere") == elsewhere / "meshes"


def test_data_dir_has_no_fallback(monkeypatch, tmp_path):
    """Without PSSD_DATA or an argument the package names no folder, not even the one the tests
    default to, wherever it is run from."""
    monkeypatch.delenv("PSSD_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    assert meshes.data_dir() is None
    monkeypatch.setenv("PSSD_DATA", "")
    assert meshes.data_dir() is None
    if models.DEFAULT_DATA_DIR.is_dir():
        monkeypatch.chdir(models.DEFAULT_DATA_DIR.parents[1])
        assert meshes.data_dir() is None


def test_data_dir_finds_each_kind_in_a_data_folder(monkeypatch, tmp_path):
    for kind in meshes.KINDS:
        (tmp_path / kind).mkdir()
    monkeypatch.setenv("PSSD_DATA", str(tmp_path))
    assert [meshes.data_dir(kind=kind) for kind in meshes.KINDS] == [
        tmp_path / kind for kind in meshes.KINDS]
    (tmp_path / "lidar").rmdir()
    assert meshes.data_dir(kind="lidar") is None  # not the lidar/ beside the data folder
    with pytest.raises(ValueError, match="unknown kind of data 'mesh'"):
        meshes.data_dir(kind="mesh")


def test_a_folder_of_meshes_still_works_as_pssd_data(monkeypatch, tmp_path):
    """PSSD_DATA once named the meshes folder itself, the other kinds beside it: a folder
    holding files but none of the kinds' folders is still read so."""
    for kind in meshes.KINDS:
        (tmp_path / kind).mkdir()
    (tmp_path / "meshes" / "fandisk.obj.gz").write_text("")
    monkeypatch.setenv("PSSD_DATA", str(tmp_path / "meshes"))
    assert meshes.data_dir() == tmp_path / "meshes"
    assert meshes.data_dir(kind="punet") == tmp_path / "punet"
    assert models.data_folder("lidar") == tmp_path / "lidar"


def test_the_tests_skip_naming_pssd_data_and_the_folder_they_looked_in(monkeypatch, tmp_path):
    monkeypatch.setenv("PSSD_DATA", str(tmp_path))
    with pytest.raises(pytest.skip.Exception) as skipped:
        data_file("lidar", "absent.laz")
    message = str(skipped.value)
    assert f"absent.laz not found in {tmp_path / 'lidar'}: set PSSD_DATA to the folder " \
           "holding meshes/, lidar/, realscans/, punet/" in message
    assert f"when PSSD_DATA is unset, they are looked for in {models.DEFAULT_DATA_DIR}" in message
    monkeypatch.delenv("PSSD_DATA")
    with pytest.raises(pytest.skip.Exception, match="PSSD_DATA") as skipped:
        data_file("punet", "absent.off.gz")
    assert f"not found in {models.DEFAULT_DATA_DIR / 'punet'}:" in str(skipped.value)


def test_package_names_no_path_outside_itself():
    """The installed package must not refer to files beside it (the tests' mesh folder, the
    project's parent folder): no such path in any of its sources."""
    import pssd_fast
    from pssd_fast import kernels

    sources = [p for module in (pssd_fast, kernels)
               for p in Path(module.__file__).parent.glob("*.py")]
    assert len(sources) > 10
    pattern = re.compile(r"""\.\./|["']shared["']|shared/(data|docs|seed)""")
    offending = [f"{p.name}:{n}: {line.strip()}" for p in sources
                 for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
                 if pattern.search(line)]
    assert offending == []
