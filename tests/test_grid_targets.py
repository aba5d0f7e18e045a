"""The grid benchmark's verdicts (``benchmarks.presets``), on hand-made cells."""
import pytest

from benchmarks import presets

pytestmark = pytest.mark.tooling


def _cell(preset, queries, mean, edge, points=100_000, noise=0.001):
    return {"points": points, "noise": noise, "preset": preset,
            "total": queries, "knn_query": 1.0, "mean_after": mean, "edge_after": edge,
            "mean_before": 8.0, "edge_before": 8.0}


BASELINE = [_cell("default", 30.0, 1.0, 2.0), _cell("fast", 3.0, 1.2, 4.0)]


def _row(cells):
    (row,) = [line for line in presets.frontier(cells, BASELINE).splitlines()
              if line.startswith("| 100,000")]
    return [column.strip() for column in row.split("|")[3:5]]


def test_the_side_by_side_takes_the_most_accurate_cheap_run_and_the_cheapest_accurate_one():
    cheap, accurate = _row([_cell("fast", 3.0, 1.3, 4.0),          # cheap, 2.0x on the edge
                            _cell("paper", 7.0, 1.1, 2.4),         # cheap, 1.2x
                            _cell("default", 9.0, 1.0, 2.1),       # within 1.05x, 9 queries
                            _cell("jet", 40.0, 0.9, 1.9)])         # within, dearer
    assert cheap.startswith("paper: 7.0 queries")
    assert cheap.endswith("(1.20 x)")
    assert accurate.startswith("default: 9.0 queries, 1.00 / 2.10 (1.05 x)")


def test_the_side_by_side_says_where_no_run_meets_a_target():
    assert _row([_cell("default", 9.0, 1.5, 2.0)]) == ["none measured", "none measured"]


def test_cells_without_a_baseline_are_left_out():
    assert "200,000" not in presets.frontier([_cell("default", 5.0, 1.0, 2.0, points=200_000)],
                                             BASELINE)


def test_small_clouds_have_their_own_cost_target():
    """20 kNN queries below 100,000 points, 8 from there."""
    assert presets.query_target(30_000) == 20.0 and presets.query_target(100_000) == 8.0
    baseline = [_cell("default", 30.0, 1.0, 2.0, points=30_000),
                _cell("fast", 3.0, 1.2, 4.0, points=30_000)]
    (row,) = [line for line in presets.frontier([_cell("default", 15.0, 1.0, 2.0, points=30_000)],
                                                baseline).splitlines()
              if line.startswith("| 30,000")]
    assert row.split("|")[3].strip().startswith("default: 15.0 queries")
    assert _row([_cell("default", 15.0, 1.0, 2.0)]) == [
        "none measured", "default: 15.0 queries, 1.00 / 2.00 (1.00 x)"]
