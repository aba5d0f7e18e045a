"""The one declaration of :func:`pssd_fast.denoise`'s parameters: complete, read by the
pipelines as declared, by ``pssd denoise``'s options and by the checks, whose errors it names."""
import argparse
import inspect
import math
import re
from pathlib import Path

import numpy as np
import pytest

import pssd_fast
from pssd_fast import cli, parameters
from pssd_fast.denoise import checked_options
from pssd_fast.parameters import BY_NAME, PARAMETERS, PIPELINES, check

PACKAGE = Path(pssd_fast.__file__).resolve().parent
#: The modules that read a pipeline's method parameters (``params["name"]``): its step, and
#: the loop of its iterations (``run.py``; the default method's: ``executor.py``).
READERS = {"paper": ("pipelines/paper.py", "run.py"), "mls": ("pipelines/mls.py", "run.py"),
           "bilateral": ("pipelines/bilateral.py", "run.py"), "default": ("executor.py",)}
#: Parameters ``pssd denoise`` takes another way: ``extras`` from ``--fields``, the
#: classification from the file, progress as its bar.
NO_OPTION = ("extras", "classification", "progress")
#: A call of :func:`checked_options` in which each pipeline runs.
RUNS = {"paper": {"preset": "paper"}, "default": {}, "bilateral": {"method": "bilateral"},
        "mls": {"method": "mls"}}


def _signature():
    return inspect.signature(pssd_fast.denoise).parameters


def _method_names():
    """The method parameters the docstring of :func:`pssd_fast.denoise` lists."""
    text = pssd_fast.denoise.__doc__
    section = text[text.index("**method_params"):text.index("Returns\n")]
    return set(re.findall(r"``([a-z_]+)``", section)) - {"exp", "ratio", "residual"}


def test_every_parameter_is_declared_once():
    names = [p.name for p in PARAMETERS]
    assert len(names) == len(set(names))
    own = [name for name in _signature() if name not in ("points", "normals", "method_params")]
    assert [p.name for p in PARAMETERS if not p.method] == own
    assert {p.name for p in PARAMETERS if p.method} == _method_names()
    assert all(p.kind in parameters.KINDS for p in PARAMETERS)


def test_the_signature_s_defaults_are_the_declared_ones():
    for name, parameter in _signature().items():
        if name in BY_NAME:
            assert parameter.default == BY_NAME[name].default, name


@pytest.mark.parametrize("pipeline", sorted(PIPELINES))
def test_each_pipeline_reads_the_method_parameters_declared_for_it(pipeline):
    read = set()
    for module in READERS[pipeline]:
        text = (PACKAGE / module).read_text(encoding="utf-8")
        read |= set(re.findall(r'params\["([a-z_]+)"\]', text))
    declared = {p.name for p in PARAMETERS
                if p.method and pipeline in (p.pipelines or PIPELINES)}
    assert read == declared


def test_the_public_names_derive_from_the_declaration():
    assert pssd_fast.METHODS == ("robust", "bilateral", "mls")
    assert parameters.PAPER_ONLY == ("h", "radius_factor", "delta", "alpha", "beta",
                                     "likelihood")
    assert parameters.DEFAULT_ONLY == ("sigma_n", "shift_normals")
    for method, defaults in parameters.METHOD_DEFAULTS.items():
        assert defaults == {p.name: p.default for p in PARAMETERS
                            if p.method and method in p.methods}
    # The run's parameters, as stats reports them: the declared defaults, checked.
    assert checked_options({})["params"] == {
        **parameters.METHOD_DEFAULTS["robust"], "h": None}


def test_none_reads_as_every_parameter_s_default():
    """``None`` is ``"auto"`` where a parameter takes it, and the declared default elsewhere
    (``preset=None`` used to be an unknown preset, ``extras=None`` a TypeError)."""
    for p in PARAMETERS:
        assert check(p.name, None) == check(p.name, p.default), p.name


def test_every_declared_default_passes_its_own_check():
    for p in PARAMETERS:
        checked = check(p.name, p.default)
        if p.auto or p.default is None:
            assert checked is None, p.name
        else:
            assert checked == p.default, p.name


def _options():
    """``pssd denoise``'s options by dest."""
    parser = cli._parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a for a in sub.choices["denoise"]._actions}


def test_the_cli_options_come_from_the_declaration():
    options = _options()
    for p in PARAMETERS:
        if p.name in NO_OPTION:
            assert p.name not in options
            continue
        option = options[p.name]
        flag = "--no-shift-normals" if p.name == "shift_normals" else (
            "--" + p.name.replace("_", "-"))
        assert flag in option.option_strings, p.name
        assert option.help.startswith(p.help), p.name
        if p.kind == "bool":
            # A flag: the declared default where it is not given.
            assert option.default == (None if p.auto else p.default), p.name
            assert option.nargs == 0 or isinstance(option, argparse.BooleanOptionalAction)
            continue
        if p.kind in ("int", "float"):
            assert option.type is {"int": int, "float": float}[p.kind], p.name
        if p.method or p.auto:
            assert option.default is None, p.name  # the library's choice
        else:
            assert option.default == p.default, p.name
        if p.kind == "choice" and not p.method:
            assert tuple(option.choices) == p.choices, p.name
    assert cli.METHOD_OPTIONS == {p.name: (p.methods, p.help) for p in PARAMETERS
                                  if p.method and p.kind != "bool"}


def test_a_cli_option_s_help_says_its_methods_and_default():
    options = _options()
    assert options["delta"].help.endswith("(0.2); method robust (preset paper)")
    assert options["sigma_n"].help.endswith("(0.05); method robust (presets default and fast)")
    assert options["h"].help.endswith("; method robust (preset paper) or mls")
    assert "exp, ratio, residual (exp)" in options["likelihood"].help


BAD = [
    ("iterations", 0, ValueError, "iterations must be at least 1; got 0"),
    ("iterations", 1.5, TypeError, "iterations must be an integer; got 1.5"),
    ("k", 9, ValueError, "k must be at least 10; got 9"),
    ("k", True, TypeError, "k must be an integer; got True"),
    ("n_jobs", 0, ValueError, "n_jobs must be a positive integer, -1 or None"),
    ("n_jobs", "2", TypeError, "n_jobs must be an integer; got '2'"),
    ("lam", 1.5, ValueError, r"lam must lie in [0.0, 1.0]; got 1.5"),
    ("lam", "auto", TypeError, "lam must be a real number; got 'auto'"),
    ("h", 0.0, ValueError, "h must be positive; got 0.0"),
    ("h", "wide", TypeError, "h must be a real number; got 'wide'"),
    ("delta", math.inf, ValueError, "delta must be finite; got inf"),
    ("sigma_n", -0.1, ValueError, "sigma_n must be positive; got -0.1"),
    ("sigma_c", np.nan, ValueError, "sigma_c must be finite; got nan"),
    ("duplicate_tolerance", -1.0, ValueError, "must be a finite distance of at least 0"),
    ("duplicate_tolerance", True, TypeError, "duplicate_tolerance must be a real number"),
    ("extras", 1, TypeError, "extras must be True or False; got 1"),
    ("keep_normals", "yes", TypeError, "keep_normals must be True or False; got 'yes'"),
    ("rebuild_graph", "yes", TypeError, "rebuild_graph must be True, False or 'auto'"),
    ("method", "magic", ValueError,
     "unknown method 'magic'; choose one of 'robust', 'bilateral', 'mls'"),
    ("preset", "fastest", ValueError, "unknown preset 'fastest'"),
    ("likelihood", "cubic", ValueError,
     "unknown likelihood 'cubic'; choose one of 'exp', 'ratio', 'residual'"),
    ("orient", "down", ValueError, "unknown orient 'down'"),
    ("orient", [1.0, 2.0], ValueError, "orient must be 'outward', 'up' or a viewpoint"),
    ("progress", 3, TypeError, "progress must be True, False, None or a callable"),
]


@pytest.mark.parametrize("name, value, error, message", BAD)
def test_a_bad_value_gets_the_declared_error(name, value, error, message):
    with pytest.raises(error, match=re.escape(message)):
        check(name, value)
    # denoise's own check says the same, in a run that uses the parameter.
    pipeline = (BY_NAME[name].pipelines or ("default",))[0]
    run = {**RUNS[pipeline], name: value} if name not in ("method", "preset") else {name: value}
    with pytest.raises(error, match=re.escape(message)):
        checked_options(run)


def _good(p, rng):
    """A value ``p`` takes, drawn by ``rng``."""
    if p.auto and rng.random() < 0.2:
        return rng.choice(["auto", None])
    if p.kind == "int":
        return int(rng.integers(p.low, p.low + 500)) if p.name != "n_jobs" else int(
            rng.choice([-1, 1, 2, 64]))
    if p.kind == "float":
        low = 0.0 if p.low is None else p.low
        high = 1e3 if p.high is None else p.high
        value = float(rng.uniform(low, high))
        return value if value > low or not p.low_open else high
    if p.kind == "bool":
        return [True, False, np.bool_(True), np.bool_(False)][rng.integers(4)]
    if p.kind in ("choice", "orient"):
        return str(rng.choice(p.choices))
    return p.default


@pytest.mark.parametrize("seed", range(5))
def test_good_values_pass(seed):
    rng = np.random.default_rng(seed)
    for p in PARAMETERS:
        if p.name in ("classification", "classes", "progress"):
            continue  # checked with the points
        for _ in range(10):
            value = _good(p, rng)
            checked = check(p.name, value)
            if p.auto and (value is None or value == "auto"):
                assert checked is None
            else:
                assert checked == value and type(checked) is not np.bool_, (p.name, value)
            checked_options({**RUNS[(p.pipelines or ("default",))[0]], p.name: value})
    checked_options({"preset": "paper", "lam": 0.0, "rebuild_graph": False, "k": 10})


def test_the_tiled_runs_take_every_declared_parameter_and_no_other():
    pytest.importorskip("dask")
    from pssd_fast.tiled import runner

    runner._check_options({p.name: p.default for p in PARAMETERS})
    with pytest.raises(TypeError, match="unknown parameter.*smoothness; tiled runs take"):
        runner._check_options({"smoothness": 1, "k": 20})


def test_a_declaration_outside_the_checks_is_refused():
    with pytest.raises(ValueError, match="parameter x"):
        parameters.Parameter("x", "float", 1.0, "x", low=1.0, low_open=True)
    with pytest.raises(ValueError, match="parameter x"):
        parameters.Parameter("x", "complex", 1.0, "x")
