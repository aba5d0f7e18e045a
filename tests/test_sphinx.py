"""The API reference builds, without a warning (docs/conf.py)."""
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
pytest.importorskip("numpydoc")

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_the_api_reference_builds_without_warnings(tmp_path):
    from sphinx.cmd.build import build_main

    status = build_main(["-W", "--keep-going", "-q", "-b", "html", str(DOCS),
                         str(tmp_path / "html")])
    assert status == 0
    page = (tmp_path / "html" / "api" / "denoise.html").read_text()
    assert "rebuild_graph" in page and "Returns" in page  # the docstrings made it in
