"""Synthetic clouds: reproducibility, exact ground truth, noise statistics, area uniformity.

Expected values (areas, bounding boxes, distances, edge curves) are computed here from the shape
definitions, independently of the implementation in ``pssd_fast.datasets``.
"""
import numpy as np
import pytest

from pssd_fast import datasets
from benchmarks.meshes import segment_distance

NAMES = sorted(datasets.GENERATORS)
GAUSS_ABS_MEAN = np.sqrt(2.0 / np.pi)  # E|N(0, 1)|

# cad_part in its own (unscaled) coordinates: bbox [-1.5, 1] x [-0.5, 0.5] x [-0.3, 0.3].
CAD_H = 0.3
CAD_CENTRE = np.array([-0.25, 0.0, 0.0])
CAD_SCALE = 1.0 / np.sqrt(2.5**2 + 1.0**2 + 0.6**2)
CAD_PROFILE_AREA = 2.0 + np.pi * 0.5**2 / 2 - 0.6 * 0.5
CAD_PERIMETER = 2.0 + 0.5 + 0.6 + 0.5 + 1.4 + np.pi * 0.5


def cad_to_scaled(p):
    return (np.asarray(p, dtype=float) - CAD_CENTRE) * CAD_SCALE


def cad_to_unscaled(p):
    return np.asarray(p) / CAD_SCALE + CAD_CENTRE


def cad_inside(p):
    """Inside test of the unscaled part, written independently of the implementation."""
    x, y, z = p.T
    rect = (x >= -1) & (x <= 1) & (y >= -0.5) & (y <= 0.5)
    disk = (x + 1) ** 2 + y**2 <= 0.25
    notch = (x >= 0.4) & (y >= 0)
    return (rect | disk) & ~notch & (np.abs(z) <= CAD_H)


def polyline_segments(points):
    points = np.asarray(points, dtype=float)
    return points[:-1], points[1:]


def cad_edge_segments(n_arc=4096):
    """The sharp edges of the unscaled part as segments (the arc as a fine polyline)."""
    corners = [(-1, -0.5), (1, -0.5), (1, 0), (0.4, 0), (0.4, 0.5), (-1, 0.5)]
    angle = np.linspace(np.pi / 2, 3 * np.pi / 2, n_arc + 1)[1:]
    arc = np.column_stack([-1 + 0.5 * np.cos(angle), 0.5 * np.sin(angle)])
    profile = np.vstack([corners, arc])
    a, b = [], []
    for z in (-CAD_H, CAD_H):
        ring = np.column_stack([profile, np.full(len(profile), z)])
        sa, sb = polyline_segments(ring)
        a.append(sa)
        b.append(sb)
    for x, y in corners[1:5]:
        a.append([[x, y, -CAD_H]])
        b.append([[x, y, CAD_H]])
    return np.vstack(a), np.vstack(b)


@pytest.fixture(scope="module")
def clouds():
    """One 50k-point cloud of every shape (built once: the statistical tests share them)."""
    return {name: datasets.make(name, n_points=50_000, noise=0.005, seed=7) for name in NAMES}


# -- shapes, types, reproducibility -------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_shapes_dtypes_and_readonly(name):
    cloud = datasets.make(name, n_points=1234, seed=1)
    assert cloud.name == name
    for array in (cloud.points, cloud.clean, cloud.normals):
        assert array.shape == (1234, 3) and array.dtype == np.float64
        assert not array.flags.writeable
    assert cloud.edge_distance.shape == (1234,) and cloud.edge_distance.dtype == np.float64
    assert isinstance(cloud.noise_sigma, float) and isinstance(cloud.diagonal, float)
    assert cloud.surface_distance(cloud.points[:5]).shape == (5,)
    assert name in repr(cloud) and "1234" in repr(cloud)


@pytest.mark.parametrize("name", NAMES)
def test_single_point(name):
    cloud = datasets.make(name, n_points=1, seed=0)
    assert cloud.points.shape == (1, 3)


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_bit_identical_other_seed_differs(name):
    a = datasets.make(name, n_points=2000, seed=5)
    b = datasets.make(name, n_points=2000, seed=5)
    c = datasets.make(name, n_points=2000, seed=6)
    for field in ("points", "clean", "normals", "edge_distance"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert a.points.tobytes() == b.points.tobytes()
    assert not np.array_equal(a.points, c.points)
    assert not np.array_equal(a.clean, c.clean)


@pytest.mark.parametrize("name", NAMES)
def test_noise_only_changes_points(name):
    quiet = datasets.make(name, n_points=1000, noise=0.0, seed=2)
    loud = datasets.make(name, n_points=1000, noise=0.02, seed=2)
    assert np.array_equal(quiet.points, quiet.clean)
    assert quiet.noise_sigma == 0.0
    assert np.array_equal(quiet.clean, loud.clean)
    assert loud.noise_sigma == pytest.approx(0.02 * loud.diagonal)


@pytest.mark.parametrize("name, diagonal", [
    ("plane", np.sqrt(2)), ("sphere", np.sqrt(3)), ("cylinder", np.sqrt(0.6**2 * 2 + 0.8**2)),
    ("cube", np.sqrt(3)), ("cad_part", 1.0)])
def test_diagonal_matches_clean_bbox(clouds, name, diagonal):
    cloud = clouds[name]
    assert cloud.diagonal == pytest.approx(diagonal, rel=1e-12)
    # 50k samples get within a hair of the extremes of these shapes.
    assert np.linalg.norm(np.ptp(cloud.clean, axis=0)) == pytest.approx(diagonal, rel=1e-3)


# -- ground truth ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_clean_points_on_surface_and_unit_normals(clouds, name):
    cloud = clouds[name]
    assert cloud.surface_distance(cloud.clean).max() < 1e-12 * cloud.diagonal
    assert np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_distance_never_exceeds_noise_displacement(clouds, name):
    # The clean point is on the surface, so the surface is at most that far away.
    cloud = clouds[name]
    assert np.all(cloud.surface_distance(cloud.points)
                  <= np.linalg.norm(cloud.points - cloud.clean, axis=1) + 1e-15)


def test_normals_plane_sphere_cylinder(clouds):
    assert np.array_equal(clouds["plane"].normals, np.tile([0.0, 0.0, 1.0], (50_000, 1)))
    sph = clouds["sphere"]
    assert np.allclose(sph.normals, sph.clean / 0.5, atol=1e-12)
    cyl = clouds["cylinder"]
    cap = np.isclose(np.abs(cyl.clean[:, 2]), 0.4, rtol=0, atol=1e-15)
    assert np.array_equal(cyl.normals[cap, 2], np.sign(cyl.clean[cap, 2]))
    assert np.allclose(cyl.normals[~cap, :2], cyl.clean[~cap, :2] / 0.3, atol=1e-12)
    assert np.all(cyl.normals[~cap, 2] == 0)


def test_normals_cube_follow_dominant_coordinate(clouds):
    cube = clouds["cube"]
    axis = np.argmax(np.abs(cube.clean), axis=1)
    rows = np.arange(len(axis))
    expected = np.zeros_like(cube.normals)
    expected[rows, axis] = np.sign(cube.clean[rows, axis])
    assert np.array_equal(cube.normals, expected)


def test_normals_cad_part_point_outwards(clouds):
    cloud = clouds["cad_part"]
    eps = 1e-4
    keep = cloud.edge_distance > 10 * eps  # a step along the normal stays off the other faces
    p, n = cloud.clean[keep], cloud.normals[keep]
    assert not cad_inside(cad_to_unscaled(p + eps * n)).any()
    assert cad_inside(cad_to_unscaled(p - eps * n)).all()
    assert np.allclose(cloud.surface_distance(p + eps * n), eps, rtol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_noisy_distance_matches_half_normal_mean(clouds, name):
    cloud = clouds[name]
    if name == "plane":
        # Its boundary is not a sharp edge, but it still changes the distance near it.
        far = np.minimum(cloud.clean[:, :2], 1 - cloud.clean[:, :2]).min(axis=1)
    else:
        far = cloud.edge_distance
    far = far > 5 * cloud.noise_sigma
    assert far.sum() > 30_000
    mean = cloud.surface_distance(cloud.points[far]).mean()
    assert mean == pytest.approx(cloud.noise_sigma * GAUSS_ABS_MEAN, rel=0.02)
    # And the noise itself is isotropic with the advertised sigma.
    assert np.std(cloud.points - cloud.clean, axis=0) == pytest.approx(
        [cloud.noise_sigma] * 3, rel=0.02)


@pytest.mark.parametrize("query, expected", [
    ((0.5, 0.5, 0.3), 0.3), ((-1.0, 0.5, 0.0), 1.0), ((2.0, 2.0, 1.0), np.sqrt(3.0)),
    ((-0.3, -0.4, 0.0), 0.5), ((0.2, 0.9, -0.1), 0.1)])
def test_plane_distance_hand_values(clouds, query, expected):
    assert clouds["plane"].surface_distance([query])[0] == pytest.approx(expected, abs=1e-15)


@pytest.mark.parametrize("name, query, expected", [
    ("sphere", (0, 0, 0), 0.5), ("sphere", (1, 0, 0), 0.5), ("sphere", (0, 0.3, 0.4), 0.0),
    ("cube", (0, 0, 0), 0.5), ("cube", (0.25, 0, 0), 0.25), ("cube", (1, 0, 0), 0.5),
    ("cube", (1, 1, 0), np.sqrt(0.5)), ("cube", (1, 1, 1), np.sqrt(0.75)),
    ("cylinder", (0, 0, 0), 0.3), ("cylinder", (0.1, 0, 0.35), 0.05),
    ("cylinder", (0.5, 0, 0.6), np.sqrt(0.08)), ("cylinder", (0, 0, 1), 0.6)])
def test_closed_shape_distance_hand_values(clouds, name, query, expected):
    assert clouds[name].surface_distance([query])[0] == pytest.approx(expected, abs=1e-15)


@pytest.mark.parametrize("query, expected", [
    # inside the notch, near the concave vertical edge at (0.4, 0)
    ((0.6, 0.2, 0.0), 0.2), ((0.5, 0.1, 0.0), 0.1), ((0.45, 0.3, 0.0), 0.05),
    # inside the part, diagonally off the concave edge: the nearest point is the edge itself
    ((0.3, -0.1, 0.0), np.sqrt(0.02)),
    # outside, past the convex edge at (1, 0): max(rectangle, -notch) would give 0.2 here
    ((1.2, 0.2, 0.0), np.sqrt(0.08)), ((1.2, 0.2, 0.4), 0.3),
    # on the surface: the concave edge itself, a notch face, a cap
    ((0.4, 0.0, 0.1), 0.0), ((0.7, 0.0, -0.2), 0.0), ((0.0, 0.0, 0.3), 0.0),
    # deep inside: nearest is the top cap; inside and outside the rounded end
    ((0.0, 0.0, 0.25), 0.05), ((-0.6, 0.0, 0.0), 0.3), ((-0.8, 0.45, 0.0), 0.05),
    ((-1.3, 0.0, 0.0), 0.2), ((-1.7, 0.0, 0.0), 0.2),
    ((-1.7, 0.0, 0.5), np.sqrt(0.08))])
def test_cad_part_distance_hand_values(clouds, query, expected):
    got = clouds["cad_part"].surface_distance(cad_to_scaled([query]))[0]
    assert got == pytest.approx(expected * CAD_SCALE, abs=1e-14)


def test_cad_part_bbox_is_centred_unit_diagonal(clouds):
    clean = clouds["cad_part"].clean
    lo, hi = clean.min(axis=0), clean.max(axis=0)
    assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-4)
    assert np.allclose(0.5 * (lo + hi), 0.0, atol=1e-4)
    assert np.allclose(hi - lo, np.array([2.5, 1.0, 0.6]) * CAD_SCALE, atol=1e-4)


# -- area uniformity ------------------------------------------------------------------------------


def assert_fraction(hits, n, p, n_sigma=5.0):
    """``hits`` out of ``n`` is within ``n_sigma`` binomial standard errors of ``n p``."""
    assert abs(hits / n - p) < n_sigma * np.sqrt(p * (1 - p) / n), (hits / n, p)


def test_cube_faces_get_a_sixth_each(clouds):
    cube = clouds["cube"]
    face = np.argmax(np.abs(cube.normals), axis=1) * 2 + (cube.normals.sum(axis=1) < 0)
    # Shuffled: the order of the points does not give their face away.
    assert np.count_nonzero(np.diff(face)) > len(face) // 2
    counts = np.bincount(face, minlength=6)
    for hits in counts:
        assert_fraction(hits, len(face), 1 / 6)
    # Within a face: the central quarter (|u|, |v| < 1/4) holds a quarter of its points.
    top = cube.clean[cube.normals[:, 2] == 1]
    assert_fraction(np.sum(np.abs(top[:, :2]).max(axis=1) < 0.25), len(top), 0.25)


def test_cylinder_caps_get_their_area_share(clouds):
    cyl = clouds["cylinder"]
    on_caps = np.abs(cyl.normals[:, 2]) == 1
    assert_fraction(on_caps.sum(), len(on_caps), 0.3 / (0.3 + 0.8))
    r = np.hypot(cyl.clean[on_caps, 0], cyl.clean[on_caps, 1])
    assert_fraction(np.sum(r < 0.15), len(r), 0.25)


def test_cad_part_caps_and_patches_get_their_area_share(clouds):
    cloud = clouds["cad_part"]
    n = len(cloud.clean)
    on_caps = np.abs(cloud.normals[:, 2]) == 1
    cap_area = 2 * CAD_PROFILE_AREA
    wall_area = CAD_PERIMETER * 2 * CAD_H
    assert_fraction(on_caps.sum(), n, cap_area / (cap_area + wall_area))
    assert_fraction(np.sum(on_caps & (cloud.normals[:, 2] > 0)), on_caps.sum(), 0.5)
    p = cad_to_unscaled(cloud.clean)
    # On the caps: the half disk's share of the profile area.
    assert_fraction(np.sum(p[on_caps, 0] < -1), on_caps.sum(),
                    np.pi * 0.25 / 2 / CAD_PROFILE_AREA)
    # On the wall: the arc's share of the perimeter, the notch floor's share (0.6), and z.
    wall = p[~on_caps]
    assert_fraction(np.sum(wall[:, 0] < -1), len(wall), np.pi * 0.5 / CAD_PERIMETER)
    floor = np.isclose(wall[:, 1], 0.0, atol=1e-12) & (wall[:, 0] > 0.4)
    assert_fraction(floor.sum(), len(wall), 0.6 / CAD_PERIMETER)
    assert_fraction(np.sum(wall[:, 2] > 0.15), len(wall), 0.25)


def test_plane_is_uniform(clouds):
    clean = clouds["plane"].clean
    assert np.all(clean[:, 2] == 0) and clean[:, :2].min() >= 0 and clean[:, :2].max() <= 1
    assert_fraction(np.sum(clean[:, 0] < 0.3), len(clean), 0.3)
    assert_fraction(np.sum(clean[:, 1] > 0.9), len(clean), 0.1)


# -- edge distance --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["plane", "sphere"])
def test_no_sharp_edges_means_infinite_edge_distance(clouds, name):
    assert np.all(np.isinf(clouds[name].edge_distance))


def test_cube_edge_distance(clouds):
    cube = clouds["cube"]
    # Face centre: 0.5 * side from every edge.
    centre = np.argmin(np.linalg.norm(cube.clean - [0, 0, 0.5], axis=1))
    assert cube.edge_distance[centre] == pytest.approx(0.5, abs=0.01)
    # The sample nearest to the edge x = y = 0.5 is at its distance from that edge.
    near = np.argmin(np.hypot(cube.clean[:, 0] - 0.5, cube.clean[:, 1] - 0.5))
    assert cube.edge_distance[near] == pytest.approx(
        np.hypot(cube.clean[near, 0] - 0.5, cube.clean[near, 1] - 0.5), abs=1e-15)
    assert cube.edge_distance[near] < 1e-3
    # Every sample against the 12 edges as explicit segments.
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)])
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8)
             if np.sum(corners[i] != corners[j]) == 1]
    assert len(pairs) == 12
    a, b = corners[[i for i, _ in pairs]], corners[[j for _, j in pairs]]
    assert np.allclose(cube.edge_distance, segment_distance(cube.clean, a, b), atol=1e-14)


def test_cylinder_edge_distance(clouds):
    cyl = clouds["cylinder"]
    angle = np.linspace(0, 2 * np.pi, 4097)
    a, b = [], []
    for z in (-0.4, 0.4):
        ring = np.column_stack([0.3 * np.cos(angle), 0.3 * np.sin(angle), np.full(4097, z)])
        sa, sb = polyline_segments(ring)
        a.append(sa)
        b.append(sb)
    sub = slice(0, 3000)
    expected = segment_distance(cyl.clean[sub], np.vstack(a), np.vstack(b))
    # The polyline deviates from the circle by 0.3 (1 - cos(pi / 4096)) < 1e-7.
    assert np.allclose(cyl.edge_distance[sub], expected, atol=2e-7)


def test_cad_part_edge_distance(clouds):
    cloud = clouds["cad_part"]
    a, b = cad_edge_segments()
    sub = slice(0, 3000)
    expected = CAD_SCALE * segment_distance(cad_to_unscaled(cloud.clean[sub]), a, b)
    assert np.allclose(cloud.edge_distance[sub], expected, atol=1e-7)
    # The arc/line junctions are smooth: wall points right next to them are not near an edge.
    p = cad_to_unscaled(cloud.clean)
    junction = (np.abs(p[:, 0] + 1) < 0.01) & (np.abs(np.abs(p[:, 1]) - 0.5) < 1e-12) \
        & (np.abs(p[:, 2]) < 0.1)
    assert junction.any()
    assert np.all(cloud.edge_distance[junction] > 0.19 * CAD_SCALE)


# -- argument checking ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("kwargs, error, text", [
    ({"n_points": 0}, ValueError, "n_points"),
    ({"n_points": -5}, ValueError, "-5"),
    ({"n_points": 10.0}, TypeError, "n_points"),
    ({"n_points": True}, TypeError, "n_points"),
    ({"noise": -0.1}, ValueError, "-0.1"),
    ({"noise": float("nan")}, ValueError, "noise"),
    ({"noise": "0.1"}, TypeError, "noise"),
    ({"seed": -1}, ValueError, "seed"),
    ({"seed": None}, TypeError, "seed"),
])
def test_bad_arguments(name, kwargs, error, text):
    with pytest.raises(error, match=text):
        datasets.make(name, **kwargs)


@pytest.mark.parametrize("name, kwargs", [
    ("sphere", {"radius": 0}), ("cube", {"side": -1.0}), ("cylinder", {"height": np.inf}),
    ("cylinder", {"radius": -0.3})])
def test_bad_shape_parameters(name, kwargs):
    (key, value), = kwargs.items()
    with pytest.raises(ValueError, match=key):
        datasets.make(name, **kwargs)


def test_make_unknown_name_lists_valid_names():
    with pytest.raises(ValueError, match="torus") as info:
        datasets.make("torus")
    for name in NAMES:
        assert name in str(info.value)
    with pytest.raises(TypeError):
        datasets.make(3)


def test_surface_distance_rejects_bad_queries(clouds):
    with pytest.raises(ValueError, match="shape"):
        clouds["cube"].surface_distance(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="non-finite"):
        clouds["cube"].surface_distance([[0.0, np.nan, 0.0]])


def test_errors_are_in_the_paper_s_unit():
    from types import SimpleNamespace

    cloud = datasets.cube(n_points=2000, noise=0.01, seed=4)
    moved = np.linalg.norm(cloud.points - cloud.clean, axis=1)
    before, after, disp, edge = cloud.errors(
        SimpleNamespace(points=cloud.clean, displacement=moved))
    unit = 1e-4 * cloud.diagonal
    np.testing.assert_allclose(before, cloud.surface_distance(cloud.points) / unit)
    assert after.max() < 1e-6 and np.allclose(disp, moved / unit)
    assert before.mean() > 50 and 0 < edge.sum() < edge.size
