"""The API reference builds, without a warning, and links to the docs it cites (docs/conf.py)."""
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.tooling

pytest.importorskip("sphinx")
pytest.importorskip("numpydoc")

DOCS = Path(__file__).resolve().parent.parent / "docs"


# It documents pssd_fast.tiled, which does not import while it is rewritten.
def test_the_api_reference_builds_without_warnings_and_links_the_docs_it_cites(tmp_path):
    from sphinx.cmd.build import build_main

    html = tmp_path / "html"
    status = build_main(["-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(html)])
    assert status == 0
    page = (html / "api" / "denoise.html").read_text()
    assert "rebuild_graph" in page and "Returns" in page  # the docstrings made it in
    assert "figure_set" in (html / "api" / "pictures.html").read_text()
    files = (html / "api" / "io.html").read_text()
    assert "pssd_fast.io.PointCloud" in files and "Examples" in files
    # Every mention of a Markdown doc is a link to its copy in the site.
    linked = set()
    for name in ("denoise", "stages", "tiled", "pictures", "io"):
        text = (html / "api" / f"{name}.html").read_text()
        linked |= set(re.findall(r'href="\.\./([\w.-]+\.md)"', text))
        outside_links = re.sub(r"<a [^>]*>.*?</a>", "", text, flags=re.S)
        assert not re.search(r"docs/[\w.-]+\.md|README", outside_links), name
    assert {"ALGORITHM.md", "DECISIONS.md", "README.md", "benchmarks.md"} <= linked
    for target in linked:
        assert (html / target).is_file(), target
    assert (html / "README.md").read_text() == (DOCS.parent / "README.md").read_text()
