"""benchmarks/howlong.py: the seconds table of the default preset, end to end at a tiny size."""
import json

import pytest

from benchmarks import howlong

pytestmark = pytest.mark.tooling


def test_howlong_writes_the_table_and_the_cells(tmp_path):
    cells = howlong.main(["--sizes", "1000", "--noises", "0.005", "--threads", "1",
                          "--repeats", "1", "--out", str(tmp_path)])
    (cell,) = cells
    assert cell["threads"] == 1 and cell["iterations"] == 2 and cell["k"] >= 2
    assert 0 < cell["knn_query"] < cell["seconds"]
    text = (tmp_path / "howlong.md").read_text()
    assert "cores" in text and "numba" in text and "one run" in text and "Load average" in text
    assert f"| 1,000 | 0.50% | {cell['seconds']:.2f} | " in text
    saved = json.loads((tmp_path / "howlong.json").read_text())
    assert saved["cells"] == cells and saved["machine"] == howlong.describe_machine()


def test_the_table_has_a_row_per_cloud_and_a_column_pair_per_thread_count():
    cells = [{"points": 10_000, "noise": 0.001, "threads_asked": t, "seconds": s,
              "knn_query": 0.5, "k": 96, "iterations": 4}
             for t, s in ((1, 4.0), (2, 2.5))]
    lines = howlong.table(cells, [1, 2, 16]).splitlines()
    assert lines[0] == ("| points | noise | 1 thread (s) | x kNN | 2 threads (s) | x kNN | "
                        "16 threads (s) | x kNN | k, iterations |")
    assert lines[2] == "| 10,000 | 0.10% | 4.00 | 8.0 | 2.50 | 5.0 | - | - | 96, 4 |"
