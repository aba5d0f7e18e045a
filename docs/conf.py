"""Sphinx configuration of the API reference (``pip install ".[docs]"``, then
``sphinx-build -W -b html docs docs/_build``; tests/test_sphinx.py builds it the same way)."""
import re
from pathlib import Path

import pssd_fast

project = "pssd_fast"
release = version = pssd_fast.__version__
extensions = ["sphinx.ext.autodoc", "sphinx.ext.intersphinx", "numpydoc"]
# The API pages only: the Markdown pages of docs/ are read on the repository's site as they are.
root_doc = "index"
exclude_patterns = ["_build", "*.md", "notes"]
autodoc_default_options = {"members": False}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
intersphinx_mapping = {}
html_theme = "alabaster"

DOCS = Path(__file__).resolve().parent
#: The Markdown pages that docstrings cite ("docs/DECISIONS.md", "README, ..."), copied into
#: the site's root as they are (a browser shows them as text), so that links to them work
#: wherever the site is served.
html_extra_path = sorted(p.name for p in DOCS.glob("*.md")) + ["../README.md"]
# A cited page: docs/NAME.md (also in double backquotes) or the README.
CITED = re.compile(r"(``)?(docs/([\w.-]+\.md)|\bREADME(?:\.md)?\b)(``)?")


def _link(match, up):
    """The mention in ``match`` as a link to the page's copy in the site's root."""
    text, page = match.group(2), match.group(3) or "README.md"
    if page != "README.md" and not (DOCS / page).is_file():
        return match.group(0)  # not one of the pages: left as written
    return f"`{text} <{up}{page}>`__"


def link_cited_docs(app, what, name, obj, options, lines):
    """Turn the docstrings' mentions of the Markdown docs into links to them."""
    up = "../" * app.env.docname.count("/")
    lines[:] = [CITED.sub(lambda m: _link(m, up), line) for line in lines]


def setup(app):
    # After numpydoc (priority 500) has turned the sections into reST.
    app.connect("autodoc-process-docstring", link_cited_docs, priority=600)
