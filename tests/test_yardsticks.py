"""The learned denoisers' benchmark and the real range scans (``benchmarks.punet``,
``benchmarks.rawscans``): their metrics and sampling on hand-made cases, each script end to end
at a small size."""
import gzip
import json

import numpy as np
import pytest

from benchmarks import meshes, metrics, punet, rawscans, versus

from .conftest import data_file

pytestmark = pytest.mark.tooling

pcu = pytest.importorskip("point_cloud_utils")

TRIANGLE = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
            np.array([[0, 1, 2]]))


def _triangle_reference(p, a, b, c):
    """Squared distance to a triangle, plainly: the plane's foot where it falls inside, else
    the nearest point of the three edges."""
    n = np.cross(b - a, c - a)
    best = np.inf
    if n @ n > 0:
        foot = p - ((p - a) @ n) / (n @ n) * n
        u, v = np.linalg.lstsq(np.column_stack([b - a, c - a]), foot - a, rcond=None)[0]
        if u >= 0 and v >= 0 and u + v <= 1:
            best = float((p - foot) @ (p - foot))
    for s, e in ((a, b), (b, c), (a, c)):
        length = (e - s) @ (e - s)
        t = 0.0 if length == 0 else min(1.0, max(0.0, (p - s) @ (e - s) / length))
        q = s + t * (e - s)
        best = min(best, float((p - q) @ (p - q)))
    return best


def test_a_point_on_a_triangle_scores_zero_and_a_point_at_distance_d_scores_d_squared():
    vertices, faces = TRIANGLE
    on = np.array([[0.25, 0.25, 0.0]])
    assert metrics.triangle_distance_squared(on[0], *vertices) == [0.0]
    d = 0.3
    above = on + [0.0, 0.0, d]
    assert metrics.triangle_distance_squared(above[0], *vertices) == pytest.approx([d * d])
    # Both directions: the point is d from the mesh, and the triangle d from its nearest point.
    assert metrics.point_to_mesh_squared(above, vertices, faces) == pytest.approx(2 * d * d)
    assert metrics.point_to_mesh_squared(on, vertices, faces) == pytest.approx(0.0, abs=1e-24)
    assert metrics.chamfer_squared(above, on) == pytest.approx(2 * d * d)
    assert metrics.chamfer_squared(on, on) == 0.0
    # One point alone is scored as well as many (point-cloud-utils misreads a single row).
    assert metrics.surface_distance(above, vertices, faces) == pytest.approx([d])


def test_chamfer_counts_each_direction_over_its_own_points():
    clean = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    denoised = np.array([[0.0, 0, 0]])  # the second clean point is 1 away from it
    assert metrics.chamfer_squared(denoised, clean) == pytest.approx(0.0 + 0.5)


def test_triangle_distance_matches_a_plain_reference_in_every_region_and_degenerate():
    rng = np.random.default_rng(1)
    a, b, c = rng.normal(size=(3, 3))
    cases = [(a, b, c), (a, a, c), (a, b, a + 2 * (b - a)), (a, a, a)]  # flat, segment, point
    for corners in cases:
        points = rng.normal(scale=2.0, size=(200, 3))
        got = metrics.triangle_distance_squared(points, *(np.tile(x, (200, 1)) for x in corners))
        assert got == pytest.approx([_triangle_reference(p, *corners) for p in points],
                                    rel=1e-9, abs=1e-12)


def test_every_triangle_finds_its_nearest_point_exactly():
    rng = np.random.default_rng(2)
    vertices = rng.normal(size=(40, 3))
    faces = rng.integers(0, 40, size=(60, 3))  # some of zero area, none dropped
    points = rng.normal(size=(500, 3))
    expected = [min(_triangle_reference(p, *vertices[f]) for p in points) for f in faces[:3]]
    got = metrics.faces_to_points(points, vertices, faces)
    assert got.shape == (60,)
    assert got[:3] == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # Point-to-mesh's first half is point-cloud-utils' distance, squared.
    dist, _, _ = pcu.closest_points_on_mesh(points, vertices, faces)
    assert metrics.point_to_mesh_squared(points, vertices, faces) == pytest.approx(
        np.mean(dist ** 2) + got.mean())


def _thin_reference(points, n):
    """Remove the point nearest to another, lower row first, until ``n`` remain (O(m^2))."""
    alive = list(range(len(points)))
    while len(alive) > n:
        sub = points[alive]
        d = np.linalg.norm(sub[:, None] - sub[None], axis=2)
        np.fill_diagonal(d, np.inf)
        gap = d.min(axis=1)
        alive.pop(int(np.flatnonzero(gap == gap.min())[0]))
    return np.array(alive)


def test_thinning_removes_the_closest_points_first():
    rng = np.random.default_rng(3)
    points = rng.random((120, 3))
    for n in (120, 100, 61, 1):
        assert np.array_equal(punet.thin(points, n), _thin_reference(points, n))
    with pytest.raises(ValueError, match="cannot thin"):
        punet.thin(points, 121)


def test_poisson_samples_are_exactly_n_reproducible_and_normalised():
    vertices = np.array([[0.0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [0, 0, 1], [2, 0, 1],
                         [2, 1, 1], [0, 1, 1]])
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                      [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    first = punet.poisson_sample(vertices, faces, 700, seed=5)
    assert first.shape == (700, 3)
    assert np.array_equal(first, punet.poisson_sample(vertices, faces, 700, seed=5))
    clean, moved = punet.normalise(first, vertices)
    assert np.linalg.norm(clean, axis=1).max() == pytest.approx(1.0)
    assert 0.5 * (clean.min(axis=0) + clean.max(axis=0)) == pytest.approx(np.zeros(3))
    # The mesh moves with the sample: the samples stay on it.
    dist, _, _ = pcu.closest_points_on_mesh(clean, moved, faces)
    assert dist.max() < 1e-9
    with pytest.raises(ValueError, match="clock"):
        punet.poisson_sample(vertices, faces, 10, seed=0)


def test_off_files_are_read_with_their_polygons_fanned(tmp_path):
    path = tmp_path / "quad.off.gz"
    with gzip.open(path, "wt") as fh:
        fh.write("OFF\n# a comment\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    vertices, faces = meshes.read_off(path)
    assert vertices.shape == (4, 3)
    assert faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 9\n")
    with pytest.raises(ValueError, match="out of range"):
        meshes.read_off(bad)
    bad.write_text("PLY\n")
    with pytest.raises(ValueError, match="not an OFF"):
        meshes.read_off(bad)


def _punet_data():
    return data_file("punet", "fandisk.off.gz").parent


def test_punet_runs_end_to_end_on_one_mesh(tmp_path):
    data = _punet_data()
    rows = punet.main(["--meshes", "fandisk", "--sizes", "3000", "--noise", "0.02",
                       "--peers", "--data", str(data), "--out", str(tmp_path), "--quiet"])
    (row,) = rows
    assert row["points"] == 3000 and row["knn_seconds"] > 0
    assert row["ours"]["default"]["cd"] < row["noisy"]["cd"]
    assert row["ours"]["default"]["p2m"] < row["noisy"]["p2m"]
    text = (tmp_path / "punet.md").read_text()
    assert "| **default** |" in text and "P2P-Bridge (ECCV 2024), published" in text
    assert "| fandisk | 3K | 2% |" in text
    assert json.loads((tmp_path / "punet.json").read_text())["rows"][0]["mesh"] == "fandisk"


def test_punet_takes_the_peers_where_they_install(tmp_path):
    data = _punet_data()
    absent = versus.missing_peers(["jet", "o3d_mls"])
    if absent:
        pytest.skip(absent)
    rows = punet.main(["--meshes", "casting", "--sizes", "1000", "--noise", "0.01",
                       "--peers", "jet", "o3d_mls", "--data", str(data), "--out",
                       str(tmp_path), "--quiet"])
    assert set(rows[0]["peers"]) == {"jet", "o3d_mls"}
    assert rows[0]["peers"]["jet"]["cd_setting"] in versus.PEER_SETTINGS["jet"]
    assert "best CGAL jet" in (tmp_path / "punet.md").read_text()
    # The peers' scores are cached: a second run runs none of them.
    assert "casting|1000|0.01" in json.loads((tmp_path / "punet_peers.json").read_text())[
        "cells"]


def test_registration_puts_a_view_on_the_reference():
    rotation = rawscans.rotation(0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))
    assert rotation @ [1.0, 0, 0] == pytest.approx([0.0, 1.0, 0.0])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    assert rawscans.boundary_vertices(faces, 5).tolist() == [True] * 4 + [False]


def test_rawscans_runs_end_to_end_on_one_view(tmp_path):
    data = data_file("realscans", "bun000.ply.gz").parent
    absent = versus.missing_peers(["jet"])
    peers = [] if absent else ["jet"]
    rows = rawscans.main(["--views", "bun000", "--every", "25", "--peers", *peers, "--data",
                          str(data), "--out", str(tmp_path), "--quiet"])
    (row,) = rows
    assert row["points"] == -(-40256 // 25)
    raw = row["rows"]["raw view"]
    assert 0 < raw["median"] < raw["mean"] < 10  # the raw view lies on the reference
    assert set(rawscans.OURS[i][0] for i in range(len(rawscans.OURS))) <= set(row["rows"])
    text = (tmp_path / "rawscans.md").read_text()
    assert "| **default** |" in text
    assert ("CGAL jet (k=48, 2 passes)" in text) == bool(peers)
