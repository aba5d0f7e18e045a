"""The package layout: kernels stand alone, and nothing refers outside the package."""
import ast
from pathlib import Path

import pssd_fast

PACKAGE = Path(pssd_fast.__file__).resolve().parent
#: What kernel modules may import: numpy, numba and two modules of the standard library.
#: Where compiled code is cached (files, hashes, warnings) is ``pssd_fast.jit``'s business.
KERNEL_IMPORTS = {"math", "threading", "numba", "numpy"}


def _imports(path):
    """(level, top-level module name) of every import in ``path``."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield 0, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            yield node.level, (node.module or "").split(".")[0]


def test_kernels_import_nothing_from_the_python_layer():
    files = sorted((PACKAGE / "kernels").glob("*.py"))
    assert len(files) >= 10
    for path in files:
        for level, name in _imports(path):
            # Relative imports stay inside kernels/ (level 1); absolute ones are allow-listed.
            assert level in (0, 1), f"{path.name} imports from outside kernels/ (level {level})"
            if level == 0:
                assert name in KERNEL_IMPORTS, f"{path.name} imports {name}"


def test_the_layout_check_catches_an_import_of_the_python_layer(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from ..stages import mls_fit\nimport pssd_fast\n")
    assert list(_imports(bad)) == [(2, "stages"), (0, "pssd_fast")]


def test_the_package_refers_to_no_path_outside_itself():
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert "shared/" not in text and "shared\" /" not in text, path
        assert ".parent.parent.parent" not in text, path
