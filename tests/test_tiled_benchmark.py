"""benchmarks/tiled.py: one in-core and one tiled cell measured in their own processes, at a
tiny size."""
import pytest

from benchmarks import stages, tiled

pytestmark = pytest.mark.tooling


def test_a_tiled_cell_times_its_passes_and_writes_the_in_core_points(tmp_path):
    pytest.importorskip("distributed")
    ((n, source),) = stages.cad_parts([20_000], tiled.NOISE, tmp_path)
    reference, out = tmp_path / "reference.npy", tmp_path / "tiled.npy"
    in_core = tiled.measure("in-core", source, reference, 1, 1)
    cell = tiled.measure("tiled", source, out, 10_000, 1)
    assert in_core["tiles"] is None and in_core["file_passes"] == 0.0
    assert cell["tiles"]["count"] >= 2 and 0.0 < cell["file_passes"] < cell["seconds"]
    assert cell["k"] == in_core["k"] and len(cell["worker_peaks"]) == 1
    assert tiled.same(out, reference) == "True"
