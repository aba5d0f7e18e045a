"""The project's texts: what a reader outside the tracker can follow."""
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.tooling

ROOT = Path(__file__).resolve().parent.parent

# The docs, the package, the benchmarks and the tests: a reader cannot look an issue up.
TEXTS = sorted(p for folder in ("docs", "pssd_fast", "benchmarks", "tests")
               for p in (ROOT / folder).rglob("*")
               if p.suffix in (".md", ".py", ".toml", ".txt"))
TEXTS += [ROOT / "README.md", ROOT / "pyproject.toml"]
ISSUE = re.compile(r"\b[Ii]ssues? #?\d+")


def test_no_text_cites_an_issue_number():
    cited = [f"{path.relative_to(ROOT)}:{n}"
             for path in TEXTS if path.is_file()
             for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
             if ISSUE.search(line)]
    assert len(TEXTS) > 50 and not cited, cited


# Citations of a page (docs/DECISIONS.md here): the file name, then one or more quoted section
# titles (a title may be the start of a heading), as in ``(DECISIONS.md, "Thin walls")``,
# ``docs/DECISIONS.md ("Numerics")`` or a Markdown link to the file followed by the titles. A
# citation of a page as it was at a commit (``ALGORITHM.md at aed3026, "Routes"``) is history,
# not one of these.
DECISIONS = ROOT / "docs" / "DECISIONS.md"
#: The pages whose sections are cited: each docs/ page, the records of retired designs
#: (docs/history/) and the README.
PAGES = {name: ROOT / "docs" / f"{name}.md" for name in (
    "DECISIONS", "ALGORITHM", "benchmarks", "tiled", "cli", "interop", "architecture")}
PAGES["README"] = ROOT / "README.md"
PAGES.update({page.stem: page for page in (ROOT / "docs" / "history").glob("*.md")})


def _citation(name):
    # A docs/ page is named with its extension (``cli, "_read"`` is code, not a citation).
    suffix = r"(?:\.md)?" if name in ("DECISIONS", "README") else r"\.md"
    return re.compile(rf'\b{name}{suffix}`?(?:\]\([^)\s]*\))?(?:\s*,\s*|\s*\(\s*)'
                      r'((?:"[^"]+"(?:\s*(?:,|and)\s*(?=")|\s*(?:,\s*)?and\s+(?="))?)+)')


CITATION = _citation("DECISIONS")
CITING = sorted(p for folder in ("docs", "pssd_fast", "benchmarks", "tests")
                for p in (ROOT / folder).rglob("*") if p.suffix in (".md", ".py", ".rst"))
CITING += [ROOT / "README.md"]


def joined(text):
    """The text as one line: each line stripped of its indent and comment marks (``#``,
    ``#:``), so that a title wrapped across lines of a docstring or comment reads whole."""
    return " ".join(re.sub(r"^\s*(?:#+:?\s*)?", "", line).strip()
                    for line in text.splitlines())


def citations(text, citation=CITATION):
    return [title for match in citation.finditer(joined(text))
            for title in re.findall(r'"([^"]+)"', match.group(1))]


def headings(page=DECISIONS):
    return [" ".join(line.lstrip("#").split()) for line in page.read_text().splitlines()
            if re.match(r"#{1,4} ", line)]


def test_citations_are_found_across_lines_and_in_lists():
    d = "DECISIONS" + ".md"  # not a citation of this file itself
    text = (f'x = 1  # kept (docs/{d}, "One default on every\n'
            f'    # cloud: the edges route"); {d} ("Numerics")\n'
            f'"""... ({d}, "Stages", "Regions of 64\n    points at once") and'
            f' docs/{d}, "Beyond the paper" and "Scan sizes"; [docs/{d}]'
            f'({d}), "Scan sizes: coarse to fine"; {d} says so, "not this"')
    assert citations(text) == ["One default on every cloud: the edges route", "Numerics",
                               "Stages", "Regions of 64 points at once", "Beyond the paper",
                               "Scan sizes", "Scan sizes: coarse to fine"]


@pytest.mark.parametrize("name", sorted(PAGES))
def test_every_citation_of_a_page_names_one_of_its_sections(name):
    titles = headings(PAGES[name])
    citation = _citation(name)
    found = [(path.relative_to(ROOT), title) for path in CITING if path.is_file()
             for title in citations(path.read_text(errors="replace"), citation)]
    missing = [f"{path}: {title!r}" for path, title in found
               if not any(heading.startswith(title) for heading in titles)]
    assert len(found) >= {"DECISIONS": 40, "ALGORITHM": 20}.get(name, 0) and not missing, missing


def test_the_links_of_decisions_its_notes_and_history_lead_to_files():
    pages = [DECISIONS] + sorted((ROOT / "docs" / "notes").glob("*.md")) + sorted(
        (ROOT / "docs" / "history").glob("*.md"))
    broken = [f"{page.relative_to(ROOT)}: {target}" for page in pages
              for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text())
              if not re.match(r"[a-z]+:|#", target)
              and not (page.parent / target.split("#")[0]).exists()]
    assert len(pages) > 5 and not broken, broken


def _readme_section(title):
    text = (ROOT / "README.md").read_text()
    start = text.index(title)
    return text[start:text.index("\n#", start + len(title))]


def test_the_readme_table_of_automatic_choices_holds_the_code_s_thresholds():
    """At most 8 rows of the default method's constants, each the code's value."""
    import ast

    from pssd_fast import method, noise, plan
    names = {"CELL": method.CELL, "RADIUS": method.RADIUS, "LIST": method.LIST,
             "ITERATIONS": method.ITERATIONS, "TEST": method.TEST, "REFINE": method.REFINE,
             "BLEND": method.BLEND,
             "PROBE": noise.PROBE, "PRESETS": plan.PRESETS}
    rows = [[cell.strip().strip("`") for cell in line.strip("|").split("|")]
            for line in _readme_section("### Automatic choices").splitlines()
            if line.startswith("| ") and "constant |" not in line]
    checked = [(constant, value) for *_, value, constant in rows if constant]
    assert 4 <= len(checked) and len(rows) <= 8
    for constant, value in checked:
        assert eval(constant, {}, names) == ast.literal_eval(value), constant


def test_the_readme_shows_denoise_s_signature():
    import inspect

    import pssd_fast

    shown = re.search(r"^denoise\(points.*?\*\*method_params\)",
                      (ROOT / "README.md").read_text(), re.S | re.M).group(0)
    assert re.sub(r"\s+", "", shown) == re.sub(
        r"\s+", "", f"denoise{inspect.signature(pssd_fast.denoise)}").replace("'", '"')


def test_every_extra_the_texts_name_is_one_of_pyproject_s():
    toml = (ROOT / "pyproject.toml").read_text()
    section = toml[toml.index("[project.optional-dependencies]"):]
    section = section[:section.index("\n[", 1)]
    extras = set(re.findall(r"^(\w+) = \[", section, re.M))
    # pip install 'pssd_fast[viz]' or ".[io,viz]", and "the ``viz`` extra" (not "extra bytes").
    install = re.compile(r"(?:pssd_fast|\.)\[([a-z_,]+)\]")
    named = re.compile(r"[`'\"]+([a-z_]+)[`'\"]+ extras?\b(?! bytes)")
    found = {(str(path.relative_to(ROOT)), name)
             for path in TEXTS + CITING if path.is_file()
             for text in [path.read_text(errors="replace")]
             for name in [n for group in install.findall(text) for n in group.split(",")]
             + named.findall(text)}
    assert {"io", "viz", "dask"} <= extras and len(found) > 10
    assert sorted(f"{path}: {name}" for path, name in found if name not in extras) == []


def _page(name):
    """docs/NAME as one line: its line breaks and indents are single spaces."""
    return re.sub(r"\s+", " ", (ROOT / "docs" / name).read_text())


def test_the_surface_classes_the_pages_name_are_the_code_s():
    from pssd_fast.classes import SURFACE_CLASSES

    named = [f"{code} {name}" for code, name in SURFACE_CLASSES.items()]
    readme = re.sub(r"\s+", " ", (ROOT / "README.md").read_text())
    assert f"(ASPRS {', '.join(named)})" in readme
    assert f"ASPRS {', '.join(named[:-1])} and {named[-1]};" in _page("cli.md")
    codes = [f"{name} ({code})" for code, name in SURFACE_CLASSES.items()]
    assert f"{', '.join(codes[:-1])} and {codes[-1]};" in _page("interop.md")


def test_the_numbers_of_the_command_line_page_are_the_code_s():
    """docs/cli.md's least class, outlier neighbours, colours and framing: each as the code has
    it (its measured numbers are checked in tests/test_cli.py)."""
    from pssd_fast.classes import least_points
    from pssd_fast.core import OUTLIER_K
    from pssd_fast.pictures import colours, draw, view
    from pssd_fast.pictures.fields import CURVATURE_K

    page = _page("cli.md")
    styles = colours.STYLES
    low, high = (f"{p:.0f}" for p in colours.ROBUST_PERCENTILES)
    expected = [
        f"({least_points({})}; `--k` plus 1)",
        f"a query of {OUTLIER_K} neighbours", f"a class of {OUTLIER_K} points or fewer",
        f"`{styles['height'].cmap}`, {low}nd to {high}th percentile",
        f"grey ramp (black to light grey), {low}nd to {high}th percentile",
        f"legend naming the classes present (at most {draw.LEGEND_ROWS}, the most numerous)",
        f"`{styles['displacement'].cmap}`, 0 to its {high}th percentile",
        f"`{styles['likelihood'].cmap}`, `{styles['feature'].cmap}`, "
        f"{styles['feature'].vmin:g} to {styles['feature'].vmax:g}",
        f"`{styles['curvature'].cmap}`, {styles['curvature'].vmin:g} to "
        f"{styles['curvature'].vmax:g}",
        f"(MLS cubics over {CURVATURE_K} neighbours)",
        f"bounding box spans {view.FILL:.0%} of the drawing",
        f"`--size WIDTH` (default {draw.DEFAULT_SIZE[0]})",
        f"the picture at least {draw.FLATTEST:g} as high as wide, the drawing at most "
        f"{draw.TALLEST:g}",
        f"from {view.SCENE_ELEVATION:.0f} degrees above", f"within {view.TURN_SLACK:.0%} of "
        f"the smallest", "from {:.0f} {:.0f}.".format(*view.DEFAULT_VIEW),
    ]
    assert view.FLAT_EXTENT == 1 / 3 and page.count("under a third") >= 2
    assert [text for text in expected if text not in page] == []


def test_the_demos_the_pages_describe_are_the_commands_defaults(monkeypatch):
    """The README's quick start and docs/cli.md's ``pssd demo``: the parts they generate."""
    from pssd_fast import __main__, cli, datasets

    demo = cli._parser().parse_args(["demo"])
    assert (f"the generated part ({demo.points:,} points, noise {demo.noise:.2%} of the "
            f"diagonal)") in _page("cli.md")

    class Generated(Exception):
        """The part was asked for: nothing more of the run is needed."""

    def cad_part(**asked):
        raise Generated(asked)

    monkeypatch.setattr(datasets, "cad_part", cad_part)
    with pytest.raises(Generated) as generated:
        __main__.main([])
    asked = generated.value.args[0]
    readme = re.sub(r"\s+", " ", (ROOT / "README.md").read_text())
    assert (f"CAD-like part ({asked['n_points']:,} points, sharp edges and a curved patch, "
            f"Gaussian noise {asked['noise']:.2%} of its diagonal)") in readme
