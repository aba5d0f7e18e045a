"""The package layout: kernels stand alone, and nothing refers outside the package."""
import ast
from pathlib import Path

import pytest

import pssd_fast

pytestmark = pytest.mark.tooling

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


#: The package's layers, bottom first, as docs/architecture.md, "Layers", lists them: a module
#: imports only from its own layer and the layers before it.
LAYERS = (("kernels",),
          ("jit", "_threads", "_validation", "interop", "progress", "atomic", "stats"),
          ("graph", "core", "duplicates", "io"), ("pipelines",),
          ("noise", "method", "plan", "parameters"),
          ("run", "executor", "regions", "store"), ("denoise", "classes", "stages", "warmup"),
          ("tiled",),
          ("pictures", "datasets", "cli", "pdal_filter", "__main__", "__init__"))


def _upward_imports(package, skip=()):
    """``(module, imported unit)`` of every relative import in ``package`` (but in the units
    ``skip``) that reaches a later layer than the importing module's (a unit: a top-level
    module or subpackage)."""
    rank = {unit: i for i, units in enumerate(LAYERS) for unit in units}
    found = []
    for path in sorted(package.rglob("*.py")):
        where = list(path.relative_to(package).parts[:-1])
        unit = (where or [path.stem])[0]
        if unit in skip:
            continue
        for level, module, names in _relative_imports(path):
            base = where[:len(where) - (level - 1)]
            parts = base + (module.split(".") if module else [])
            for target in ([parts[0]] if parts else names):
                if target != unit and target != "__version__" and rank[target] > rank[unit]:
                    found.append((str(path.relative_to(package)), target))
    return found


def _relative_imports(path):
    """(level, module, names) of every relative import in ``path``."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level:
            yield node.level, node.module, [alias.name for alias in node.names]


def test_each_layer_imports_only_the_layers_below_it():
    units = {p.stem for p in PACKAGE.glob("*.py")} | {
        p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert units == {unit for layer in LAYERS for unit in layer}, "a module without a layer"
    assert _upward_imports(PACKAGE) == []


def test_only_the_array_layer_calls_kernels():
    """``core`` (and ``graph`` for the neighbour lists) wrap every kernel the rest calls."""
    callers = sorted(str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py")
                     if path.parent.name not in ("kernels", "jit")
                     and any("kernels" in (module or "").split(".")
                             or (not module and "kernels" in names)
                             for _, module, names in _relative_imports(path)))
    assert callers == ["core.py", "graph.py"]


def test_the_layer_check_catches_an_upward_import(tmp_path):
    package = tmp_path / "pkg"
    (package / "pipelines").mkdir(parents=True)
    (package / "pipelines" / "aware.py").write_text("from ..method import CELL\n")
    (package / "core.py").write_text("from . import denoise\nfrom .kernels import mls\n")
    assert _upward_imports(package) == [("core.py", "denoise"), ("pipelines/aware.py", "method")]


def test_the_layout_check_catches_an_import_of_the_python_layer(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from ..stages import mls_fit\nimport pssd_fast\n")
    assert list(_imports(bad)) == [(2, "stages"), (0, "pssd_fast")]


def test_the_package_refers_to_no_path_outside_itself():
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert "shared/" not in text and "shared\" /" not in text, path
        assert ".parent.parent.parent" not in text, path


_SUBPACKAGE_PROBE = """
import json, sys
import pssd_fast
loaded_by_import = sorted(name for name in pssd_fast.SUBPACKAGES
                          if f"pssd_fast.{name}" in sys.modules)
kinds = {name: type(getattr(pssd_fast, name)).__name__ for name in pssd_fast.SUBPACKAGES}
try:
    pssd_fast.no_such_thing
    missing = None
except AttributeError as exc:
    missing = str(exc)
print(json.dumps({"by_import": loaded_by_import, "kinds": kinds, "dir": dir(pssd_fast),
                  "missing": missing, "render": callable(pssd_fast.pictures.render)}))
"""


def test_subpackages_load_on_attribute_access_not_on_import():
    """In a fresh process: ``import pssd_fast`` loads none of them, ``pssd_fast.io`` (and the
    others) loads each, ``dir`` lists them, and an unknown name is still an AttributeError."""
    import json
    import subprocess
    import sys

    from .conftest import PACKAGE_PARENT

    run = subprocess.run([sys.executable, "-c", _SUBPACKAGE_PROBE], cwd=PACKAGE_PARENT,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    probe = json.loads(run.stdout.strip().splitlines()[-1])
    assert pssd_fast.SUBPACKAGES == ("datasets", "io", "pictures", "tiled")
    assert probe["by_import"] == []
    assert probe["kinds"] == dict.fromkeys(pssd_fast.SUBPACKAGES, "module")
    assert set(pssd_fast.SUBPACKAGES) <= set(probe["dir"]) and "denoise" in probe["dir"]
    assert probe["missing"] == "module 'pssd_fast' has no attribute 'no_such_thing'"
    assert probe["render"]
