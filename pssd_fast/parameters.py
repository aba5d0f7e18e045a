"""Every parameter of :func:`pssd_fast.denoise`, declared once: its name, kind, default, range
or choices, whether it takes ``"auto"``, the pipelines it applies to and a line of help.

:func:`pssd_fast.denoise`, the tiled runs and ``pssd denoise`` read these declarations
(docs/DECISIONS.md, "Parameters declared once").
"""
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from . import core, duplicates
from ._threads import check_n_jobs
from ._validation import (
    MIN_K, ORIENTATIONS, auto, check_choice, check_flag, check_float, check_int, check_orient,
)
from .plan import PRESETS
from .progress import reporter

#: The kinds of value a parameter takes.
KINDS = ("int", "float", "bool", "choice", "orient", "labels", "classes", "callable")
#: The pipelines of :func:`pssd_fast.denoise` and the method each belongs to.
PIPELINES = {"default": "robust", "paper": "robust", "bilateral": "bilateral", "mls": "mls"}


@dataclass(frozen=True)
class Parameter:
    """One parameter of :func:`pssd_fast.denoise`.

    Attributes
    ----------
    name : str
        Its keyword.
    kind : str
        One of :data:`KINDS`: ``"int"``, ``"float"``, ``"bool"``, ``"choice"`` (one of
        ``choices``), ``"orient"`` (a name or a viewpoint), ``"labels"`` (a class code per
        point), ``"classes"`` (codes or a name) or ``"callable"``.
    default : object
        What :func:`pssd_fast.denoise` takes where the caller gives nothing.
    help : str
        One line on what it does.
    low, high : float or int, optional
        Its range (None: unbounded on that side); ``high`` is included.
    low_open : bool
        Whether ``low`` itself is refused (``h > 0``) rather than allowed (``lam >= 0``); an
        open range starts at 0.
    choices : tuple of str
        What a ``"choice"`` takes.
    auto : bool
        Whether it takes ``"auto"``, the library's choice (and None, read as ``"auto"``).
    method : bool
        Whether it is a method parameter (``**method_params``) rather than a keyword of
        :func:`pssd_fast.denoise`'s own.
    pipelines : tuple of str
        The pipelines (:data:`PIPELINES`) that use it; empty: every one.
    checker : callable, optional
        Its own check, where its messages are its own (``value -> checked value``).
    """

    name: str
    kind: str
    default: object
    help: str
    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    choices: tuple = ()
    auto: bool = False
    method: bool = False
    pipelines: tuple = ()
    checker: Optional[Callable] = None

    def __post_init__(self):
        # An open range starts at 0 only: its message is "must be positive".
        if self.kind not in KINDS or (self.low_open and self.low != 0):
            raise ValueError(f"parameter {self.name}: kind {self.kind!r}, low {self.low}, "
                             f"low_open {self.low_open}")

    @property
    def methods(self):
        """The methods whose runs use it, in :data:`METHODS`' order."""
        used = {PIPELINES[p] for p in self.pipelines or PIPELINES}
        return tuple(m for m in dict.fromkeys(PIPELINES.values()) if m in used)

    def check(self, value):
        """``value`` checked, in the form the run uses: None for ``"auto"`` (where it takes
        it) and for None where None is its default; None elsewhere read as the default;
        TypeError or ValueError naming the parameter and the bad value otherwise."""
        if value is None and not self.auto and self.default is not None:
            value = self.default
        if self.auto or self.default is None:
            # auto(): None for "auto" and for None, else the value as given.
            left = auto(value) if self.auto else value
            if left is None:
                return None
        if self.checker is not None:
            return self.checker(value)
        if self.kind == "int":
            return check_int(value, self.name, minimum=self.low)
        if self.kind == "float":
            if self.low_open and self.low == 0:
                return check_float(value, self.name, high=self.high, positive=True)
            return check_float(value, self.name, low=self.low, high=self.high)
        if self.kind == "choice":
            return check_choice(value, self.name, self.choices)
        if self.kind == "bool":
            if self.auto:
                return check_flag(value, self.name)
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"{self.name} must be True or False; got {value!r}")
            return bool(value)
        return value  # "labels", "classes": checked with the points (pssd_fast.classes)


def _of_method(*pipelines):
    """A method parameter's fields: used by ``pipelines``."""
    return {"method": True, "pipelines": pipelines}


#: The range of a positive float.
_POSITIVE = {"low": 0.0, "low_open": True}

#: Every parameter of :func:`pssd_fast.denoise` (but ``points`` and ``normals``), its own
#: keywords in its signature's order, then the method parameters.
PARAMETERS = (
    Parameter("method", "choice", "robust", "robust (the paper's method and its refinement), "
              "bilateral (BIL) or mls (MLS projection)", choices=("robust", "bilateral", "mls")),
    Parameter("iterations", "int", "auto", "iterations (by default the preset's)", low=1,
              auto=True),
    Parameter("k", "int", "auto", f"neighbours per point, {MIN_K} to n - 1 (by default "
              f"the preset's, or chosen from the estimated noise)", low=MIN_K, auto=True),
    Parameter("lam", "float", None, "lambda, the weight of the likelihood term (by default "
              "the preset's)", low=0.0, high=1.0, pipelines=("paper",)),
    Parameter("preset", "choice", "default", "default: the feature-aware fit on cell means "
              "sized by the noise, then refined; fast: the same without the refinement; "
              "paper: the paper's method (k=25, lam=0.5, 2 iterations)",
              choices=tuple(PRESETS)),
    Parameter("rebuild_graph", "bool", "auto", "find the neighbours anew in every iteration "
              "(by default the preset's; the paper's pipeline and the baselines)", auto=True,
              pipelines=("paper", "bilateral", "mls")),
    Parameter("orient", "orient", None, f"sign of the estimated normals: "
              f"{', '.join(ORIENTATIONS)} or a viewpoint (normals towards it), made consistent "
              f"over the neighbour graph (by default each away from the centroid)",
              choices=ORIENTATIONS, checker=check_orient),
    Parameter("remove_outliers", "bool", False, "drop the points whose outlier score exceeds 1 "
              "before denoising"),
    Parameter("extras", "bool", False, "also return the likelihood and the feature intensity"),
    Parameter("duplicate_tolerance", "float", 0.0, "rows in one cube of this edge are one "
              "position, denoised as one point (0: only rows with equal coordinates)", low=0.0,
              checker=duplicates.check_tolerance),
    Parameter("classification", "labels", None, "a class code per point (LAS classification)"),
    Parameter("classes", "classes", None, "the classes to denoise, each on its own: codes, "
              "each or all", choices=("each", "all")),
    Parameter("n_jobs", "int", None, "threads (by default all cores); the result does not "
              "depend on it", low=1, checker=check_n_jobs),
    Parameter("progress", "callable", None, "True: a line per stage on stderr; or a callable "
              "given (iteration, iterations, stage, seconds)", checker=reporter),
    Parameter("h", "float", "auto", "MLS Gaussian width (by default the mean distance to the "
              "k-th neighbour)", auto=True, **_POSITIVE, **_of_method("paper", "mls")),
    Parameter("radius_factor", "float", core.FEATURE_DEFAULTS["radius_factor"],
              "R = radius_factor * mean spacing for the region-grown neighbourhood",
              **_POSITIVE, **_of_method("paper")),
    Parameter("delta", "float", core.FEATURE_DEFAULTS["delta"],
              "feature threshold delta of eq. (3)", **_POSITIVE, **_of_method("paper")),
    Parameter("alpha", "float", core.FEATURE_DEFAULTS["alpha"],
              "feature threshold alpha of eq. (3)", **_POSITIVE, **_of_method("paper")),
    Parameter("beta", "float", core.FEATURE_DEFAULTS["beta"],
              "feature threshold beta of eq. (3)", **_POSITIVE, **_of_method("paper")),
    Parameter("likelihood", "choice", "exp", "sampling likelihood form",
              choices=tuple(core.LIKELIHOOD_FORMS), **_of_method("paper")),
    Parameter("sigma_n", "float", 0.05, "normal-agreement width of the feature-aware fit",
              **_POSITIVE, **_of_method("default")),
    Parameter("shift_normals", "bool", True, "first iteration: each point's normal from the "
              "flattest nearby list, not its own PCA normal", **_of_method("default")),
    Parameter("sigma_c", "float", "auto", "BIL spatial width (by default half the list radius)",
              auto=True, **_POSITIVE, **_of_method("bilateral")),
    Parameter("sigma_s", "float", "auto", "BIL height width (by default the std of the heights)",
              auto=True, **_POSITIVE, **_of_method("bilateral")),
    Parameter("keep_normals", "bool", False, "use the given normals in every iteration "
              "instead of estimating them anew", method=True),
)
#: :data:`PARAMETERS` by name.
BY_NAME = {p.name: p for p in PARAMETERS}
#: Methods :func:`pssd_fast.denoise` offers.
METHODS = BY_NAME["method"].choices
#: Parameters of each method beyond the common ones, with their defaults.
METHOD_DEFAULTS = {m: {p.name: p.default for p in PARAMETERS if p.method and m in p.methods}
                   for m in METHODS}
#: Robust-method parameters that only the paper's pipeline uses, and those only the default
#: method uses.
PAPER_ONLY = tuple(p.name for p in PARAMETERS if p.method and p.pipelines
                   and "robust" in p.methods and "default" not in p.pipelines)
DEFAULT_ONLY = tuple(p.name for p in PARAMETERS if p.method and p.pipelines
                     and "robust" in p.methods and "paper" not in p.pipelines)


def check(name, value):
    """``value`` of parameter ``name`` checked (:meth:`Parameter.check`)."""
    return BY_NAME[name].check(value)
