"""docs/benchmarks.md's generated tables: up to date, rebuilt in place, errors that say why."""
import shutil

import pytest

from benchmarks import report

pytestmark = pytest.mark.tooling

TABLE = "| a | b |\n|---|---|\n| 1 | 2 |"


@pytest.fixture
def results(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "x.md").write_text(f"Machine: test\n\n{TABLE}\n\nA note.\n")
    return folder


def block(source, content):
    return f"<!-- begin {source} -->\n\n{content}\n\n<!-- end {source} -->\n"


def test_the_doc_is_up_to_date_with_the_results():
    assert report.update(check=True) == [], "run python -m benchmarks.report"


def test_update_replaces_each_block_and_keeps_the_prose(tmp_path, results):
    doc = tmp_path / "doc.md"
    prose = ["# Title\n\nHand-written, | with a bar.\n", "\nBetween.\n", "\nThe end.\n"]
    doc.write_text(prose[0] + block("results/x.md", "old") + prose[1]
                   + block("results/x.md#table", "| a | b |\n|---|---|\n| 1 | 3 |") + prose[2])
    assert report.update(doc, results, check=True) == ["results/x.md", "results/x.md#table"]
    assert "old" in doc.read_text()
    assert report.update(doc, results) == ["results/x.md", "results/x.md#table"]
    whole = (results / "x.md").read_text().strip()
    assert doc.read_text() == (prose[0] + block("results/x.md", whole) + prose[1]
                               + block("results/x.md#table", TABLE) + prose[2])
    assert report.update(doc, results) == []


def test_a_changed_table_of_the_doc_is_put_back(tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    shutil.copy(report.DOC, doc)
    text = doc.read_text()
    # The sheets table's first row as the results file has it, with its default's cell edited.
    row = next(line for line in (report.RESULTS / "sheets.md").read_text().splitlines()
               if line.startswith("| 4 | 0.80 | "))
    edited = "| 4 | 0.80 | 9.99 |" + row[len("| 4 | 0.80 | "):].split("|", 1)[1]
    changed = text.replace(row, edited).replace("# Benchmarks", "# Benchmarks, edited")
    assert changed.count("9.99 |") == text.count("9.99 |") + 1
    doc.write_text(changed)
    assert report.main(["--check", "--doc", str(doc)]) == 1
    assert "results/sheets.md#table" in capsys.readouterr().out
    assert report.main(["--doc", str(doc)]) == 0
    assert doc.read_text() == text.replace("# Benchmarks", "# Benchmarks, edited")


@pytest.mark.parametrize("body, error, match", [
    (block("results/missing.md", ""), FileNotFoundError, "results/missing.md"),
    (block("results/x.md#nothing", ""), KeyError, "unknown view 'nothing'"),
    ("<!-- begin results/x.md -->\n", ValueError, "no end marker"),
    ("<!-- end results/x.md -->\n", ValueError, "line 2: .* a begin marker"),
    ("<!-- begin results/x.md -->\n<!-- end results/y.md -->\n", ValueError,
     "line 3: .* the open block results/x.md"),
])
def test_a_bad_block_is_refused_and_the_doc_left_alone(tmp_path, results, body, error, match):
    doc = tmp_path / "doc.md"
    doc.write_text("Prose.\n" + body)
    with pytest.raises(error, match=match):
        report.update(doc, results)
    assert doc.read_text() == "Prose.\n" + body


def test_a_results_file_without_a_table_is_refused(tmp_path, results):
    (results / "prose.md").write_text("No table here.\n")
    doc = tmp_path / "doc.md"
    doc.write_text(block("results/prose.md#table", ""))
    with pytest.raises(ValueError, match="no markdown table"):
        report.update(doc, results)


def test_the_second_table_and_the_bullets_are_views_of_their_own(tmp_path, results):
    second = "| c |\n|---|\n| 4 |"
    (results / "two.md").write_text(f"{TABLE}\n\nTimes:\n\n{second}\n\n- first\n- second\n\n"
                                    "- not this one\n")
    assert report.render("results/two.md#times", results) == second
    assert report.render("results/two.md#standings", results) == "- first\n- second"
    with pytest.raises(ValueError, match="no markdown table number 2"):
        report.render("results/x.md#times", results)
    with pytest.raises(ValueError, match="no bulleted list"):
        report.render("results/x.md#standings", results)
