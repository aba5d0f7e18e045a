"""The Examples sections of the main public functions run as doctests, on small clouds."""
import doctest
import importlib

import pytest

#: The functions whose docstrings must hold an Examples section that runs: (module, name).
DOCUMENTED = [("pssd_fast", "denoise"), ("pssd_fast.tiled", "denoise"),
              ("pssd_fast.tiled", "denoise_file"), ("pssd_fast", "estimate_normals"),
              ("pssd_fast", "outlier_score"), ("pssd_fast.io", "read"), ("pssd_fast.io", "write")]


@pytest.mark.parametrize("module, name", DOCUMENTED, ids=[f"{m}.{n}" for m, n in DOCUMENTED])
def test_the_example_runs_and_shows_what_it_prints(module, name):
    if module == "pssd_fast.tiled":
        pytest.importorskip("dask")
    function = getattr(importlib.import_module(module), name)
    assert "\n    Examples\n    --------\n" in function.__doc__, f"{module}.{name}: no Examples"
    tests = doctest.DocTestFinder().find(function, f"{module}.{name}", globs={})
    # Every example checks some output, not only that its statements run.
    assert sum(bool(example.want) for test in tests for example in test.examples) >= 2
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    report = []
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.tries >= 5 and runner.failures == 0, "".join(report)
