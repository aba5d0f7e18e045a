"""The run plan (pssd_fast.plan): made once, frozen, what each preset and method decides, and
what ``stats`` says of it (docs/ALGORITHM.md, "The plan")."""
import dataclasses
import math

import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, method, noise, plan
from pssd_fast.graph import morton_order


@pytest.fixture(scope="module")
def quiet():
    """3,000 points of the generated part, noise well below the spacing; Morton order,
    relative to the centre of their box, as denoise hands them to the plan."""
    points = np.array(datasets.make("cad_part", n_points=3000, noise=0.001, seed=4).points)
    points = points[morton_order(points)]
    low, high = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (low + high)
    return np.ascontiguousarray(points - centre), low - centre


def _make(quiet, preset, pipeline, **options):
    points, low = quiet
    return plan.make(points, preset, pipeline, distinct=len(points), low=low, **options)


@pytest.mark.parametrize("preset", ["default", "fast"])
def test_the_default_method_s_plan(quiet, preset):
    """The plan holds the probe's reading and what it sized from it (the sizes themselves are
    checked against the reference end to end, tests/test_method.py): the cells, the lists on
    the means and their reach, the refinement's lists (none under "fast"); no graph rebuilt;
    ``stats["plan"]`` says the same."""
    found = _make(quiet, preset, "default")
    probe = noise.probe(quiet[0])
    assert found.noise == probe
    assert (found.pipeline, found.iterations) == ("default", method.ITERATIONS)
    assert found.edge >= method.CELL["spacing"] * probe.spacing
    assert method.LIST["shortest"] <= found.k <= method.LIST["longest"]
    assert found.bound > found.edge
    np.testing.assert_array_equal(found.low, quiet[1])
    if preset == "fast":
        assert found.refine is None
    else:
        k_r, bound_r, iterations_r = found.refine
        assert k_r >= method.REFINE["k"] and bound_r > 0.0
        assert iterations_r == method.REFINE["iterations"]
    assert not found.rebuild_graph and set(found.probe) == {"seconds"}
    assert found.describe() == {
        "method": "default", "iterations": found.iterations, "k": found.k,
        "cell_edge": found.edge, "bound": found.bound, "noise": probe.record(),
        "refine": None if found.refine is None else {**found.refine._asdict(),
                                                     "own_noise": found.own_noise,
                                                     "own_sigma": None}}


def test_own_lists_span_the_noise():
    """Lists of ``k`` points span ``sqrt(k / pi)`` spacings: wide enough at ``TEST["span"]``
    noise widths, not below."""
    span = method.TEST["span"]
    assert method.own_lists_span(40, 1.0, math.sqrt(40 / math.pi) / span)
    assert not method.own_lists_span(40, 1.0, 1.0001 * math.sqrt(40 / math.pi) / span)


def _ordered_centred(points):
    points = np.asarray(points, np.float64)
    points = points[morton_order(points)]
    return np.ascontiguousarray(points - 0.5 * (points.min(axis=0) + points.max(axis=0)))


@pytest.mark.parametrize("n_points, level, on", [(20_000, 0.04, True), (30_000, 0.08, False)])
def test_the_own_fits_decide_where_the_probe_s_noise_leaves_their_test_out(n_points, level,
                                                                           on):
    """Where the refinement's lists span fewer than TEST["span"] of the probe's noise widths,
    the plan reads the noise by the own fits (noise.own_sigma on the probe's sample) and the
    test against the own noise runs if the lists span as many of those: on the generated part
    at 20,000 points and 4% (the probe reads its edges as noise: 2.95 widths, the own fits
    3.33), not at 30,000 points and 8% (1.97 and 2.69)."""
    points = _ordered_centred(datasets.make("cad_part", n_points=n_points, noise=level,
                                            seed=2).points)
    found = plan.make(points, "default", "default", distinct=len(points),
                      low=points.min(axis=0))
    k_r, bound_r, _ = found.refine
    radius = method.list_radius(k_r, found.noise.spacing)
    assert not method.own_lists_span(k_r, found.noise.spacing, found.noise.sigma)
    assert found.own_sigma == noise.own_sigma(points, noise.sample(points), k_r, bound_r,
                                              radius)
    assert found.own_noise == method.own_lists_span(k_r, found.noise.spacing,
                                                    found.own_sigma) == on
    assert found.describe()["refine"]["own_sigma"] == found.own_sigma


def test_the_own_fits_read_the_same_bits_on_one_thread_as_on_two():
    """The reading's kernels split their lists among threads, never a sum: one thread and
    two read the same noise, to the bit."""
    from pssd_fast._threads import threads

    points = _ordered_centred(datasets.make("cad_part", n_points=20_000, noise=0.04,
                                            seed=2).points)
    read = []
    for n_jobs in (1, 2):
        with threads(n_jobs):
            read.append(plan.make(points, "default", "default", distinct=len(points),
                                  low=points.min(axis=0)).own_sigma)
    assert read[0] is not None and read[0] == read[1]


def test_the_own_fits_read_where_the_lists_span_half_the_test_s_widths():
    """The own fits' reading decides between OWN_READ and 1 times TEST["span"] of the
    probe's noise widths; beyond, the probe's noise decides; below, the lists are narrower than
    the noise can be and the test stays off."""
    span, k = method.TEST["span"], 40
    radius = method.list_radius(k, 1.0)
    for widths, reads in ((1.01 * span, False), (0.99 * span, True),
                          (1.01 * method.OWN_READ * span, True),
                          (0.99 * method.OWN_READ * span, False)):
        assert method.own_reading_decides(k, 1.0, radius / widths) == reads, widths


def test_the_callers_choices_override_the_preset_s(quiet):
    found = _make(quiet, "default", "default", k=30, iterations=3)
    assert found.k == 30 and found.iterations == 3
    assert found.bound == method.list_bound(30, found.noise.spacing, found.edge)
    # The list length is capped by the distinct positions.
    points, low = quiet
    few = plan.make(points, "default", "default", distinct=25, low=low)
    assert few.k == 24


@pytest.mark.parametrize("preset, pipeline, k, iterations, rebuild", [
    ("paper", "paper", 25, 2, True),
    ("default", "mls", None, 4, True),
    ("fast", "bilateral", 48, 2, False),
])
def test_the_paper_s_pipeline_and_the_baselines_iterate_on_the_points(quiet, preset, pipeline,
                                                                      k, iterations, rebuild):
    """Their k (the preset's, else from the noise probe's sigma over spacing through
    ``BASELINE_K``; no probe runs where the preset gives k), iterations and rebuild_graph."""
    found = _make(quiet, preset, pipeline)
    assert (found.pipeline, found.iterations, found.rebuild_graph) == (pipeline, iterations,
                                                                      rebuild)
    assert found.noise is None and found.edge is None and found.refine is None
    if k is not None:
        assert found.k == k and found.probe is None
    else:
        read = noise.probe(quiet[0])
        assert found.probe["noise"] == read.sigma and found.probe["spacing"] == read.spacing
        assert found.probe["ratio"] == read.sigma / read.spacing < plan.BASELINE_K[0][0]
        assert found.k == found.probe["k"] == plan.BASELINE_K[0][1]  # held at the first anchor
    assert found.describe() == {"method": pipeline, "k": found.k, "iterations": iterations,
                                "rebuild_graph": rebuild}
    given = _make(quiet, preset, pipeline, k=20, iterations=1, rebuild_graph=not rebuild)
    assert (given.k, given.iterations, given.rebuild_graph, given.probe) == (
        20, 1, not rebuild, None)


def test_the_baselines_k_follows_the_noise_over_the_spacing(monkeypatch, quiet):
    """Each anchor's ratio gives its ``k``; between them ``k`` grows with the ratio; outside
    them it is held; never above the distinct positions less one."""
    ratios = []
    monkeypatch.setattr(plan, "probe", lambda points: noise.Noise(ratios[-1], 1.0, 1, {}))

    def k_at(ratio, distinct=len(quiet[0])):
        ratios.append(ratio)
        return plan.make(quiet[0], "default", "mls", distinct=distinct, low=quiet[1]).k

    for ratio, k in plan.BASELINE_K:
        assert k_at(ratio) == k
    between = [k_at(r) for r in np.geomspace(0.5, 5.0, 12)]
    assert between == sorted(between) and between[0] == 64 and between[-1] == 160
    assert len(set(between)) > 4
    assert k_at(3.0, distinct=50) == 49 and k_at(0.0) == 64


def test_a_plan_is_frozen(quiet):
    found = _make(quiet, "default", "default")
    for name, value in (("k", 3), ("bound", 1.0), ("refine", None), ("noise", None)):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(found, name, value)


@pytest.mark.parametrize("options, described", [
    ({}, "default"), ({"preset": "fast"}, "default"), ({"preset": "paper"}, "paper"),
    ({"method": "bilateral"}, "bilateral"), ({"method": "mls", "k": 20}, "mls")])
def test_stats_say_which_method_ran_and_its_plan(quiet, options, described):
    points, _ = quiet
    result = pssd_fast.denoise(points, iterations=1, **options)
    taken = result.stats["plan"]
    assert taken["method"] == result.stats["pipeline"] == described
    assert taken["k"] == result.stats["k"] and taken["iterations"] == 1
    assert "route" not in taken and "select_scales" not in result.stats["params"]
    if described == "default":
        assert taken["noise"]["sigma"] == result.stats["noise"]
        assert (taken["refine"] is None) == (options.get("preset") == "fast")
    else:
        assert taken["rebuild_graph"] == result.stats["rebuild_graph"]
        # The baselines' k from their noise probe unless given; the paper's is its preset's.
        from_probe = described in ("bilateral", "mls") and "k" not in options
        assert (result.stats["auto_k"] is not None) == from_probe


@pytest.mark.parametrize("noise_level", [0.001, 0.02])
def test_tiled_runs_follow_the_same_plan(tmp_path, noise_level):
    pytest.importorskip("dask")
    from pssd_fast import tiled

    points = np.array(datasets.make("cad_part", n_points=30_000, noise=noise_level,
                                    seed=6).points)
    whole = pssd_fast.denoise(points, iterations=1)
    tiles = tiled.denoise(points, iterations=1, tile_points=12_000, client="sync")
    assert tiles.stats["plan"] == whole.stats["plan"]
    np.testing.assert_array_equal(tiles.points, whole.points)
    np.save(tmp_path / "in.npy", points)
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", iterations=1,
                               tile_points=12_000, client="sync")
    assert stats["plan"] == whole.stats["plan"]
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), whole.points)
    # At 2% the probe's noise leaves the own test out: the own fits' reading, read from the
    # files' buckets (lists across them), decided.
    assert (whole.stats["plan"]["refine"]["own_sigma"] is not None) == (noise_level > 0.01)
