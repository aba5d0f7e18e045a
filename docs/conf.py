"""Sphinx configuration of the API reference (``pip install ".[docs]"``, then
``sphinx-build -W -b html docs docs/_build``; tests/test_sphinx.py builds it the same way)."""
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
