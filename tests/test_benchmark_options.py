"""The benchmarks' options and files at a tiny size: the thin-wall benchmark (benchmarks.sheets)
writes where it is told, and values no run can take are one-line errors."""

import json

import pytest

from benchmarks import sheets

pytestmark = pytest.mark.tooling


def test_sheets_writes_where_it_is_told(tmp_path, capsys):
    sheets.main(["--points", "1500", "--gaps", "15", "--methods", "fast", "--out",
                 str(tmp_path)])
    saved = json.loads((tmp_path / "sheets.json").read_text())
    assert saved["points"] == 1500 and list(saved["rows"][0]) == ["gap", "noisy", "fast"]
    assert "| gap (sigma) | noisy | fast |" in (tmp_path / "sheets.md").read_text()
    assert f"wrote {tmp_path / 'sheets'}.md and .json" in capsys.readouterr().err


def test_an_unknown_method_is_refused_before_any_run(capsys):
    """A misspelt name is an error, not CGAL's bilateral under that name."""
    with pytest.raises(SystemExit) as stop:
        sheets.main(["--points", "1500", "--methods", "defualt"])
    assert stop.value.code == 2 and "invalid choice: 'defualt'" in capsys.readouterr().err


@pytest.mark.parametrize("module, argv, match", [
    ("table1", ["--noise", "-0.01"], "argument --noise: -0.01 is not above 0"),
    ("table1", ["--iterations", "0"], "argument --iterations: 0 is not above 0"),
    ("table1", ["--scale", "0"], "argument --scale: 0 is not above 0"),
    ("punet", ["--sizes", "0"], "argument --sizes: 0 is not above 0"),
    ("rawscans", ["--every", "-1"], "argument --every: -1 is not above 0"),
    ("presets", ["--against", "nosuch"], "--against nosuch: no "),
])
def test_bad_option_values_are_one_line_errors(module, argv, match, capsys):
    """Values no run can take stop at once with argparse's usage error, not a traceback
    after the work nor a run of something else."""
    import importlib

    with pytest.raises(SystemExit) as stop:
        importlib.import_module(f"benchmarks.{module}").main(argv)
    assert stop.value.code == 2 and match in capsys.readouterr().err


def test_a_child_run_that_fails_says_why(tmp_path):
    """A benchmark's child process that fails stops the run with the child's own message."""
    import sys

    from benchmarks.stages import child_result

    with pytest.raises(SystemExit, match="benchmarks.nosuch failed: .*No module named"):
        child_result([sys.executable, "-m", "benchmarks.nosuch"])
