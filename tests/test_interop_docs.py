"""Every example of docs/interop.md runs: its Python blocks as they are, and its PDAL pipeline
through PDAL's contract (tests/pdal_like.py), on a small survey the test writes."""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from pssd_fast import pdal_filter

from . import pdal_like

PAGE = Path(__file__).resolve().parent.parent / "docs" / "interop.md"
#: The libraries an example may need, skipped without them (PDAL's bindings have no wheels).
OPTIONAL = ("open3d", "trimesh", "laspy", "pdal")


def blocks(language):
    """``(section, code)`` of every fenced block of ``language``, in the page's order."""
    section, found, lines, inside = None, [], [], False
    for line in PAGE.read_text().splitlines():
        if not inside and line.startswith("## "):
            section = line[3:].strip()
        elif not inside and line.strip() == f"```{language}":
            inside, lines = True, []
        elif inside and line.strip() == "```":
            inside = False
            found.append((section, "\n".join(lines) + "\n"))
        elif inside:
            lines.append(line)
    return found


def imported(code):
    """Top-level names of the modules ``code`` imports."""
    return set(re.findall(r"^(?:import|from)\s+(\w+)", code, re.MULTILINE))


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A working folder holding ``survey.laz`` where laspy can write it."""
    monkeypatch.chdir(tmp_path)
    try:
        import laspy  # noqa: F401
    except ImportError:
        return tmp_path
    pdal_like.write_las(tmp_path / "survey.laz", pdal_like.survey())
    return tmp_path


def test_the_page_has_an_example_for_each_library():
    sections = {section for section, _ in blocks("python")}
    assert {"Open3D", "trimesh", "laspy", "Structured arrays", "PDAL"} <= sections
    assert len(blocks("json")) == 1


def _ground_only(folder):
    """The laspy example's output: the ground moved, every other point as it was."""
    before, after = pdal_like.read_las("survey.laz"), pdal_like.read_las("clean.laz")
    ground = before["Classification"] == 2
    for axis in "XYZ":
        np.testing.assert_array_equal(after[axis][~ground], before[axis][~ground])
    assert (after["Z"][ground] != before["Z"][ground]).mean() > 0.5


def _written(name):
    return lambda folder: (folder / name).is_file() or pytest.fail(f"{name} not written")


#: What each section's example leaves behind, checked after it ran.
CHECKS = {"Open3D": _written("clean.ply"), "trimesh": _written("clean.ply"),
          "laspy": _ground_only}


@pytest.mark.parametrize("section, code", blocks("python"),
                         ids=[f"{s}-{i}" for i, (s, _) in enumerate(blocks("python"))])
def test_each_python_example_runs(folder, section, code):
    for name in sorted(imported(code) & set(OPTIONAL)):
        pytest.importorskip(name, reason=f"the {section} example needs {name}")
    exec(compile(code, f"{PAGE.name} ({section})", "exec"), {"__name__": "__example__"})
    if section in CHECKS:
        CHECKS[section](folder)


def test_the_pdal_pipeline_runs_as_pdal_runs_it(folder):
    """The page's pipeline, its script given as its command line does (the path that
    ``python -m pssd_fast.pdal_filter`` prints, as test_interop_pdal.py checks)."""
    pytest.importorskip("laspy")
    ((_, text),) = blocks("json")
    reader, stage, writer = json.loads(text)
    assert stage["type"] == "filters.python" and writer["type"] == "writers.las"
    stage = {**stage, "script": str(Path(pdal_filter.__file__).resolve())}
    before = pdal_like.read_las(reader)
    after = pdal_like.run_stage(stage, before)
    pdal_like.write_las(writer["filename"], after)
    written = pdal_like.read_las(folder / writer["filename"])
    chosen = np.isin(before["Classification"], json.loads(stage["pdalargs"])["classes"])
    assert chosen.sum() == 2500
    for name, values in before.items():
        rows = ~chosen if name in "XYZ" else slice(None)
        np.testing.assert_array_equal(written[name][rows], values[rows], err_msg=name)
    assert (written["Z"][chosen] != before["Z"][chosen]).mean() > 0.5
    assert "python -m pssd_fast.pdal_filter" in PAGE.read_text()
