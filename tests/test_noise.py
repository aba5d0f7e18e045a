"""The noise probe (pssd_fast.noise, kernels.noise.local_noise): the kernel against its
reference, the known noise of generated clouds read back, the calibration measured again."""
import math

import numpy as np
import pytest

from pssd_fast import core, datasets, noise
from pssd_fast.graph import knn_graph, morton_order

from . import reference
from .conftest import CLOUDS


def _ordered(points):
    """``points`` in Morton order, as the probe reads them."""
    return np.ascontiguousarray(np.asarray(points, np.float64)[morton_order(points)])


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_local_noise_matches_the_reference(name):
    """Random and degenerate clouds (planar, collinear, duplicated, eleven points): the robust
    spread and the radius of each prefix of each list. Prefixes of 9 points and more (the
    probe reads 10 and more): at 7, one point more than the quadratic's coefficients, the
    normal equations the kernel solves and the reference's least squares part by up to 2%."""
    points = CLOUDS[name]()
    k = min(25, len(points) - 1)
    lists, _ = reference.knn_lists(points, k)
    lengths = np.array(sorted({9, min(12, k), k}), np.int64)
    scale = np.empty((len(points), len(lengths)))
    radius = np.empty_like(scale)
    from pssd_fast.kernels.noise import local_noise

    # int32 lists, as the library's graphs hold them: the signature every run compiles.
    local_noise(points, np.array(lists, np.int32), lengths, scale, radius)
    want_scale, want_radius = reference.local_noise(points, lists, lengths)
    extent = float(np.ptp(points, axis=0).max())
    np.testing.assert_allclose(radius, want_radius, rtol=1e-12, atol=1e-15 * extent)
    # Exact planes and lines leave residuals of rounding only: compared to the extent.
    np.testing.assert_allclose(scale, want_scale, rtol=1e-9, atol=1e-12 * extent)
    if name in ("plane", "collinear"):
        assert scale.max() < 1e-12 * extent
    else:
        assert (np.median(scale, axis=0) > 0).all()


def test_core_local_noise_reads_the_graph_s_prefixes():
    points = _ordered(CLOUDS["sphere"]())
    graph = knn_graph(points, 30, False)
    scale, radius = core.local_noise(points, graph, np.array([12, 30], np.int64))
    lists = list(graph.indices.reshape(len(points), 30))
    want_scale, want_radius = reference.local_noise(points, lists, [12, 30])
    np.testing.assert_allclose(scale, want_scale, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(radius, want_radius, rtol=1e-12)


#: The probe's noise over the generated clouds' own (measured over these cells: plane 0.87 to
#: 1.00, the least at 20,000 points and 2%; sphere 0.96 to 1.01; cube 1.01 to 1.10).
TOLERANCE = (0.85, 1.2)


@pytest.mark.parametrize("name", ["plane", "sphere", "cube"])
@pytest.mark.parametrize("n", [5000, 20000])
@pytest.mark.parametrize("level", [0.001, 0.005, 0.02])
def test_the_probe_reads_the_noise_of_generated_clouds(name, n, level):
    cloud = datasets.make(name, n_points=n, noise=level, seed=1)
    found = noise.probe(_ordered(cloud.points))
    ratio = found.sigma / cloud.noise_sigma
    assert TOLERANCE[0] < ratio < TOLERANCE[1], ratio
    assert found.stride == 1 and set(found.readings) == set(noise.PROBE["lengths"])


def test_the_probe_reads_the_spacing_of_a_quiet_plane():
    """On a surface a list of k points covers about pi r^2 = k s^2: s is the side of the area
    a point covers (the unit square over 20,000 points: 0.00707)."""
    cloud = datasets.make("plane", n_points=20000, noise=0.0005, seed=2)
    found = noise.probe(_ordered(cloud.points))
    side = math.sqrt(np.prod(np.ptp(cloud.clean[:, :2], axis=0)) / 20000)
    assert abs(found.spacing / side - 1) < 0.05


@pytest.mark.parametrize("far", [[1e6, 1e6, 1e6], [-3e4, 0.0, 0.0]])
def test_a_stray_point_leaves_the_probe_s_spacing_as_it_was(far):
    """A point far from the rest (a stray return, a row at the origin of a georeferenced
    cloud) lists the others from afar; its radius is left out of the mean (``PROBE["stray"]``),
    which it would otherwise set alone (measured: 31.3 against 0.0071)."""
    cloud = datasets.make("plane", n_points=20000, noise=0.0005, seed=2)
    alone = noise.probe(_ordered(cloud.points))
    found = noise.probe(_ordered(np.vstack([cloud.points, far])))
    assert found.spacing == pytest.approx(alone.spacing, rel=0.01)
    assert found.sigma == pytest.approx(alone.sigma, rel=0.01)


def test_the_surface_radius_is_the_plain_mean_without_stray_points():
    radius = np.random.default_rng(0).uniform(1.0, 20.0, 1000)
    assert noise.surface_radius(radius) == np.mean(radius)
    assert noise.surface_radius(np.append(radius, 1e5)) == np.mean(radius)


@pytest.mark.parametrize("gap", [6.0, 10.0])
def test_the_probe_reads_one_sheet_s_noise_on_a_thin_plate(gap):
    """Two noisy parallel sheets ``gap`` noise widths apart: the shortest lists wide enough
    stay on one sheet (measured: 1.11 and 0.99 at 6,000 points a sheet; two sheets 4 widths
    apart read 1.5, 3 apart 1.8, as one sheet of their combined spread)."""
    sigma = 0.002
    rng = np.random.default_rng(0)
    own = np.repeat([0.0, gap * sigma], 6000)
    points = np.column_stack([rng.uniform(0, 0.35, (12000, 2)), own])
    points += rng.normal(0, sigma, points.shape)
    found = noise.probe(_ordered(points))
    assert 0.9 < found.sigma / sigma < 1.25


@pytest.mark.parametrize("name", ["plane", "sphere", "cube"])
def test_an_exact_sample_reads_no_noise(name):
    cloud = datasets.make(name, n_points=5000, noise=0.0, seed=1)
    found = noise.probe(_ordered(cloud.points))
    assert found.sigma < 1e-4 * found.spacing and found.spacing > 0


def test_a_large_cloud_is_read_on_every_stride_th_point():
    """Above ``PROBE["points"]`` the probe reads an evenly spread sample (every ``stride``-th
    point of the Morton order), and scales the sample's spacing to the whole cloud's."""
    points = _ordered(datasets.make("sphere", n_points=45_000, noise=0.003, seed=4).points)
    found = noise.probe(points)
    assert found.stride == 3
    sample = noise.probe(np.ascontiguousarray(points[::3]))
    assert found.readings == sample.readings and found.sigma == sample.sigma
    assert found.spacing == pytest.approx(sample.spacing / math.sqrt(3), rel=1e-12)


def test_a_tiny_cloud_reads_its_one_list():
    """Fewer points than the shortest length: one list of all the others."""
    found = noise.probe(_ordered(CLOUDS["tiny"]()))
    assert list(found.readings) == [10] and np.isfinite(found.sigma) and found.sigma > 0


@pytest.mark.parametrize("length", sorted(noise.CALIBRATION))
def test_invert_gives_back_the_noise_of_every_row_and_between_them(length):
    table = noise.CALIBRATION[length]
    for sigma in (1e-3, 2.0):
        for x, f in table:
            assert noise.invert(sigma * f, sigma * x, table) == pytest.approx(sigma, rel=1e-9)
        # Between two rows: log-linear.
        (x0, f0), (x1, f1) = table[3], table[4]
        x = math.sqrt(x0 * x1)
        f = math.exp(0.5 * (math.log(f0) + math.log(f1)))
        assert noise.invert(sigma * f, sigma * x, table) == pytest.approx(sigma, rel=1e-9)
    # Held at the ends: far beyond the last row's radius the reading is f's last value.
    assert noise.invert(table[-1][1], 1e6, table) == pytest.approx(1.0, rel=1e-9)
    assert noise.invert(0.0, 1.0, table) == 0.0
    reads = [noise.invert(read, 1.0, table) for read in (0.01, 0.05, 0.1, 0.3)]
    assert reads == sorted(reads)


def test_the_calibration_is_measured_again_on_a_noisy_plane():
    """What each list length reads on a plane of 20,000 uniformly random points at three noise
    levels (lists 1.5 to 14 noise widths across), away from its border: within 4% of the
    table (measured: 0.97 to 1.015)."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 1, (20000, 2))
    lengths = np.array(noise.PROBE["lengths"], np.int64)
    for sigma in (0.012, 0.005, 0.002):
        points = _ordered(np.column_stack([xy, rng.normal(0, sigma, len(xy))]))
        scale, radius = core.local_noise(points, knn_graph(points, lengths[-1], False),
                                         lengths)
        inner = ((points[:, :2] > 0.15) & (points[:, :2] < 0.85)).all(axis=1)
        for col, length in enumerate(lengths):
            x = radius[inner, col].mean() / sigma
            xs, fs = (np.log(np.array(column)) for column in zip(*noise.CALIBRATION[length]))
            table = math.exp(np.interp(math.log(x), xs, fs))
            assert abs(np.median(scale[inner, col]) / sigma / table - 1) < 0.04, (sigma, length)


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_own_variances_match_the_reference(name):
    """What the own fits read on every 5th point (their lists of 30 within a bound that cuts
    some short): the library's blocks of gathered lists against the reference's fits one
    point at a time."""
    points = _ordered(CLOUDS[name]())
    n = len(points)
    rows = np.arange(0, n, 5)
    k = min(30, n - 1)
    bound = 0.3 * float(np.ptp(points, axis=0).max())
    got = noise.sampled_variances(points, points[rows], k, bound)
    want = reference.own_variances(points, rows, k, bound)
    scale = float(np.ptp(points, axis=0).max()) ** 2
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12 * scale)


def test_own_variances_of_lists_of_one_point_and_of_none():
    """A list of the point alone reads no noise; an empty list reads NaN (no point)."""
    lists = np.zeros((3, 4, 3))
    lists[0, :3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, -0.5]]
    lists[1, 0] = [2.0, 2.0, 2.0]
    got = noise.own_variances(lists, np.array([3, 1, 0]))
    assert np.isfinite(got[0]) and got[1] == 0.0 and np.isnan(got[2])


@pytest.mark.parametrize("ratio", [1.0, 3.0])
def test_the_own_reading_gives_back_a_planes_noise(ratio):
    """On a noisy plane of the calibration's size whose noise spans 1 and 3 spacings (the
    refinement's lists about 7 and 2.4 noise widths across), the own fits' reading of 4,000
    points, read back through OWN_CALIBRATION, is the noise within 6%."""
    rng = np.random.default_rng(7)
    n = 60_000
    sigma = ratio / math.sqrt(n)
    points = _ordered(np.column_stack([rng.uniform(0, 1, (n, 2)), rng.normal(0, sigma, n)]))
    taken = noise.sample(points)
    found = noise.probe(points, taken)
    k = 160 if ratio > 2 else 80
    radius = math.sqrt(k / math.pi) * found.spacing
    assert noise.own_sigma(points, taken, k, 2.0 * radius, radius) == pytest.approx(
        sigma, rel=0.06)


def test_own_sigma_matches_the_reference(monkeypatch):
    """At most OWN_POINTS of the probe's sample read (here 100 of the 400 points of a wavy
    surface: every 4th), their mean variance read back through OWN_CALIBRATION: the
    reference's noise to round-off."""
    monkeypatch.setattr(noise, "OWN_POINTS", 100)
    points = _ordered(CLOUDS["wavy"]())
    radius = 0.1
    got = noise.own_sigma(points, noise.sample(points), 30, 0.2, radius)
    want = reference.own_sigma(points, np.arange(0, len(points), 4), 30, 0.2, radius,
                               noise.OWN_CALIBRATION)
    assert got == pytest.approx(want, rel=1e-9)


def test_own_sigma_reads_the_calibration_back():
    """``invert`` on OWN_CALIBRATION gives back the noise of every row."""
    for x, f in noise.OWN_CALIBRATION:
        assert noise.invert(0.7 * f, 0.7 * x, noise.OWN_CALIBRATION) == pytest.approx(
            0.7, rel=1e-9)
