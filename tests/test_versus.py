"""The peer comparison suite: its verdicts and its output, without running the peers."""
import json

import pytest

from benchmarks import versus

pytestmark = pytest.mark.tooling

pytest.importorskip("point_cloud_utils")


def test_best_of_takes_each_column_separately():
    family = {"a": {"mean": 1.0, "edge": 9.0, "seconds": 1.0},
              "b": {"mean": 2.0, "edge": 3.0, "seconds": 2.0}}
    assert versus.best_of(family, "mean") == (1.0, "a")
    assert versus.best_of(family, "edge") == (3.0, "b")


def test_versus_writes_the_table_from_a_peer_cache(tmp_path):
    fake = {"mean": 1e9, "edge": 0.0, "seconds": 1.0}  # peers win every edge, lose every mean
    cells = {versus._key("cad_part", 0.005, 3000): {
        family: {label: dict(fake) for label in settings}
        for family, settings in versus.PEER_SETTINGS.items()}}
    (tmp_path / versus.PEER_CACHE.name).write_text(json.dumps({"machine": "test",
                                                                "cells": cells}))
    rows = versus.main(["--shapes", "cad_part", "--noise", "0.005", "--cad-points", "3000",
                        "--out", str(tmp_path), "--quiet"])
    (row,) = rows
    assert row["default"]["mean"] < row["noisy"]["mean"]
    assert row["paper"]["mean"] < row["noisy"]["mean"]
    assert row["default"]["k"] >= 10 and row["knn_seconds"] > 0
    text = (tmp_path / "versus.md").read_text()
    assert "| cad_part\\* | 0.50% |" in text and "win / lose" in text
    assert "\\* In-sample" in text
    assert f"Cells won: {len(versus.FAMILIES)} of {2 * len(versus.FAMILIES)}." in text
    assert "cad_part 0.50% edge vs jet" in text and "cad_part 0.50% edge vs o3d_mls" in text
    assert len(json.loads((tmp_path / "versus.json").read_text())["rows"]) == 1


def _fake_cell(score):
    return {family: {label: dict(score) for label in settings}
            for family, settings in versus.PEER_SETTINGS.items()}


def test_sized_run_compares_only_real_cells(tmp_path):
    fake = {"mean": 1e9, "edge": 0.0, "seconds": 1.0}  # peers lose every mean, win every edge
    no_edge = {"mean": 1e9, "edge": None, "seconds": 1.0}
    cells = {versus._key("plane", 0.005, 2000): _fake_cell(no_edge),
             versus._key("cube", 0.005, 2000): _fake_cell(fake)}
    (tmp_path / versus.PEER_CACHE.name).write_text(json.dumps({"machine": "test",
                                                                "cells": cells}))
    rows = versus.main(["--sizes", "2000", "--shapes", "plane", "cube", "--noise", "0.005",
                        "--out", str(tmp_path), "--quiet"])
    assert [(r["shape"], r["points"]) for r in rows] == [("plane", 2000), ("cube", 2000)]
    assert rows[0]["default"]["edge"] is None and rows[0]["jet"]["edge_setting"] is None
    text = (tmp_path / "versus_sparse.md").read_text()
    assert not (tmp_path / "versus.md").exists()
    assert "| plane | 2,000 | 0.50% |" in text and "win / -" in text
    families = len(versus.FAMILIES)
    assert f"Cells won: {2 * families} of {3 * families}." in text
    assert "cube 2,000 pts 0.50% edge vs jet" in text
    assert "In-sample" not in text


def test_another_seed_draws_other_cells_and_files(tmp_path):
    first, other = versus.make_case("cube", 0.005, 2000), versus.make_case("cube", 0.005, 2000,
                                                                           seed=1)
    assert first.seed == 0 and other.seed == 1
    assert not (first.points == other.points).all()
    assert versus._key("cube", 0.005, 2000, 1) == "cube|0.005|2000|seed1"
    assert versus._key("cube", 0.005, 2000) == "cube|0.005|2000"
    fake = {"mean": 1e9, "edge": 1e9, "seconds": 1.0}
    cells = {versus._key(s, 0.005, 2000, 1): _fake_cell(fake) for s in ("cad_part", "cube")}
    (tmp_path / versus.PEER_CACHE.name).write_text(json.dumps({"machine": "test",
                                                                "cells": cells}))
    rows = versus.main(["--sizes", "2000", "--shapes", "cad_part", "cube", "--noise", "0.005",
                        "--seed", "1", "--out", str(tmp_path), "--quiet"])
    assert [r["seed"] for r in rows] == [1, 1]
    assert not any(r["in_sample"] for r in rows)  # the part's constants came from seed 0
    text = (tmp_path / "versus_sparse_seed1.md").read_text()
    assert "Noise seed: 1." in text and "In-sample" not in text
    assert not (tmp_path / "versus_sparse.md").exists()


def test_the_part_at_another_size_is_a_cell_of_its_own():
    """--cad-points other than the table's keys the part's peers by that size, so that a run
    is never scored against peers of another size."""
    keys = [key for *_, key in versus.cells(versus.parse_args(
        ["--shapes", "cad_part", "--noise", "0.0025", "0.005", "--cad-points", "10000"]))]
    assert keys == ["cad_part|0.0025|10000", "cad_part|0.005|10000"]
    keys = [key for *_, key in versus.cells(versus.parse_args(
        ["--shapes", "cad_part", "--noise", "0.0025"]))]
    assert keys == ["cad_part|0.0025"]


def test_a_cached_cell_runs_only_the_families_it_lacks(tmp_path, monkeypatch):
    fake = {"mean": 1.0, "edge": 1.0, "seconds": 1.0}
    cached = {family: {label: dict(fake) for label in versus.PEER_SETTINGS[family]}
              for family in ("jet", "bilateral")}
    path = tmp_path / versus.PEER_CACHE.name
    path.write_text(json.dumps({"machine": "test", "cells": {"cube|0.005": cached}}))
    ran = []

    def run_peers(case, log, families):
        ran.append(tuple(families))
        return {family: {"s": dict(fake, mean=2.0)} for family in families}

    monkeypatch.setattr(versus, "run_peers", run_peers)
    case = versus.make_case("cube", 0.005, 500)
    cell = versus.peer_cell(case, "cube|0.005", path, False, print)
    assert ran == [tuple(f for f in versus.FAMILIES if f not in cached)]
    assert cell["jet"] == cached["jet"] and set(cell) == set(versus.FAMILIES)
    assert json.loads(path.read_text())["cells"]["cube|0.005"] == cell
    assert versus.peer_cell(case, "cube|0.005", path, False, print) == cell  # nothing to run
    assert len(ran) == 1
    versus.peer_cell(case, "cube|0.005", path, True, print)  # refresh: every family again
    assert ran[-1] == versus.FAMILIES


def test_a_peer_library_missing_for_cells_not_cached_stops_before_any_run(tmp_path,
                                                                         monkeypatch):
    """Without Open3D and without its cells in the cache, the run stops at once, naming the
    library, rather than after the CGAL runs with a traceback."""
    from benchmarks import peers

    monkeypatch.setattr(peers, "available", lambda: {"cgal": True, "pymeshlab": False,
                                                     "open3d": False})
    monkeypatch.setattr(versus.pssd_fast, "warmup", lambda: pytest.fail("ran"))
    with pytest.raises(SystemExit, match="o3d_bilateral, o3d_mls need open3d"):
        versus.main(["--shapes", "cad_part", "--noise", "0.005", "--cad-points", "2000",
                     "--out", str(tmp_path), "--quiet"])
    assert list(tmp_path.iterdir()) == []
