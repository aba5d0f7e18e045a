"""The run plan: which route a run takes and at which sizes, decided in one place for
:func:`pssd_fast.denoise`, :func:`pssd_fast.tiled.denoise` and
:func:`pssd_fast.tiled.denoise_file` (docs/ALGORITHM.md, "Routes").

The routes of the feature-aware pipeline: ``"cells"`` (the iterations run on the means of grid
cells sized by the noise, the points are moved onto their fits last; where the noise spans
several point spacings), ``"edges"`` (the cells, then the points near features iterate on
their own lists: :mod:`pssd_fast.routes.edges`), ``"points"`` (the iterations run on the
points, each fitted over its ``k`` nearest) and ``"walks"`` (on the points, each fitted over
its own number of neighbours, ``select_scales``). The paper's pipeline and the baselines always
run on the points.
"""
import math
import time
from dataclasses import dataclass
from typing import Callable, Optional

from ..pipelines import aware
from . import coarse, edges, scales

#: Presets: the pipeline of the robust method and where ``k``, ``lam``, ``iterations`` and
#: ``rebuild_graph`` (on the input; on cell means see ``pssd_fast.routes.coarse.COARSE``)
#: come from when not given, and the most points and the neighbours of the noise probe
#: (``k="auto"``: chosen from the estimated noise, see ``pssd_fast.pipelines.aware.AUTO_K``, or
#: the coarse-to-fine route of ``pssd_fast.routes.coarse``; ``without_cells_k``: the ``k``
#: where that route finds no cells; ``scales_up_to``: the largest cloud whose points the
#: walks of ``select_scales="auto"`` take; ``light``: whether the light route of :data:`LIGHT`
#: is tried first). "default" and "fast" run the feature-aware pipeline
#: (docs/DECISIONS.md, "Beyond the paper" and "Scan sizes"); "paper" is the paper's
#: formulation.
PRESETS = {
    "default": {"pipeline": "aware", "k": None, "lam": None, "iterations": 4,
                "rebuild_graph": True, "probe": (100_000, 96), "scales_up_to": 50_000,
                "light": True},
    "fast": {"pipeline": "aware", "k": None, "lam": None, "iterations": 2,
             "rebuild_graph": False, "probe": (5_000, 32), "without_cells_k": 48,
             "scales_up_to": 0},
    "paper": {"pipeline": "paper", "k": 25, "lam": 0.5, "iterations": 2, "rebuild_graph": True,
              "probe": (100_000, 96), "scales_up_to": 0},
}

#: The light route of a preset with ``"light": True`` (the default), on clouds of more than
#: its ``scales_up_to`` points: ``fast``'s probe first; up to ``up_to`` (its ``sigma / r``,
#: the noise against the lists of 32) the run takes ``fast``'s cells and iterations and then
#: the edges pass (:mod:`pssd_fast.routes.edges`): the ``"edges"`` route. Elsewhere, or
#: where ``fast`` finds no cells, the preset's own plan. Chosen on the CAD part at 100,000
#: to 1,000,000 points (docs/DECISIONS.md, "One default on every cloud: the edges route").
LIGHT = {"up_to": 0.3}


@dataclass
class Plan:
    """What a run does, decided before its iterations.

    Attributes
    ----------
    k : int
        The iterations' neighbours (on the cell means on the cells route).
    rebuild_graph : bool
        Whether each iteration queries its lists anew.
    select_scales : bool or None
        ``select_scales`` as the run records it (None off the feature-aware pipeline).
    probe : dict or None
        The noise probe behind a ``k`` chosen from the data (``stats["auto_k"]``), else None.
    noise : float or None
        The noise the cells are sized by (cells route).
    layout : tuple or None
        The cells (cells route): the grouping of the caller's ``layout``, the cells' edge,
        ``k`` and ``rebuild_graph`` (:func:`pssd_fast.routes.coarse.layout`).
    walks : ScalePlan or None
        What the walks share (walks route; :func:`pssd_fast.routes.scales.plan`).
    lists : ListScales or None
        Lists the first iteration can take over (the probe's or the walks' plan's).
    walks_seconds : float or None
        What planning the walks took.
    iterations : int
        The iterations (on the cell means on the cells and edges routes).
    cells : str or None
        The key of :data:`pssd_fast.routes.coarse.COARSE` whose cells the run takes.
    edges : dict or None
        The edges route's pass: the flagged points' ``k``
        (:func:`pssd_fast.routes.edges.list_length`) and the zone's ``radius`` around a
        flagged cell mean (:func:`pssd_fast.routes.edges.reach`), then what the run did
        (``flagged``, ``zone``, ``held``).
    """

    k: int
    rebuild_graph: bool
    select_scales: Optional[bool]
    probe: Optional[dict]
    noise: Optional[float]
    layout: Optional[tuple]
    walks: Optional[scales.ScalePlan]
    lists: object
    walks_seconds: Optional[float]
    iterations: int
    cells: Optional[str] = None
    edges: Optional[dict] = None

    @property
    def route(self):
        """``"edges"``, ``"cells"``, ``"walks"`` or ``"points"``, from what the plan holds."""
        if self.edges is not None:
            return "edges"
        if self.cells is not None:
            return "cells"
        return "points" if self.walks is None else "walks"

    def walks_record(self):
        """What the walks' plan set, for ``stats["scales"]``; None off the walks route."""
        if self.walks is None:
            return None
        return {"lengths": self.walks.lengths.tolist(), "first": self.walks.first,
                "noise": math.sqrt(self.walks.noise2), "seconds": self.walks_seconds}

    def describe(self):
        """The plan for ``stats["plan"]`` (JSON-serialisable)."""
        return {"route": self.route, "k": self.k, "rebuild_graph": self.rebuild_graph,
                "select_scales": self.select_scales, "iterations": self.iterations,
                "cells": self.cells, "edges": self.edges}


def make(points, given, preset, *, distinct, layout: Callable, k=None, iterations=None,
         aware_pipeline=True, rebuild_graph=None, select_scales=None, sigma_n=None,
         shift_normals=True):
    """The :class:`Plan` of a run on ``points`` (Morton order; a ``(n, 3)`` array or what
    offers ``shape`` and ``[::step]`` as one, :class:`pssd_fast.tiled.ondisk.Buckets`).

    Parameters
    ----------
    points, given
        The distinct positions, relative to the centre, and the caller's normals or None.
    preset : str
        A key of :data:`PRESETS`.
    distinct : int
        The number of distinct positions.
    layout : callable
        ``layout(noise, cells)``: :func:`pssd_fast.routes.coarse.layout` of the cloud at
        that noise for the ``cells`` key of ``COARSE`` (its grouping first), or None.
    k, iterations : int or None
        The caller's (None: from the noise probe where the preset has none; the preset's or
        the light route's iterations).
    aware_pipeline : bool
        Whether the run takes the feature-aware pipeline (its routes and ``select_scales``).
    rebuild_graph, select_scales : bool or None
        The caller's (None: the preset and the cloud decide).
    sigma_n, shift_normals
        The feature-aware pipeline's, for the walks' plan.
    """
    setting = PRESETS[preset]
    if (setting.get("light") and aware_pipeline and k is None and not select_scales
            and distinct > setting["scales_up_to"]):
        light = _light(points, given, layout, iterations, rebuild_graph)
        if light is not None:
            return light
    iterations = setting["iterations"] if iterations is None else iterations
    probe = lists = noise = found = None
    if k is None and setting["k"] is None:
        k, probe, lists = aware.choose_k(points, given, *setting["probe"])
        probe["coarse"] = None
        if aware_pipeline and probe["ratio"] >= coarse.COARSE[preset]["min_ratio"]:
            noise = aware.noise_sigma(points, given, probe)
            found = layout(noise, preset)
        if found is None:
            k = min(setting.get("without_cells_k") or k, distinct - 1)
            if lists is not None and k > probe["probe_k"]:
                lists = None  # too short to serve: freed before the longer lists are built
    elif k is None:
        k = setting["k"]
    if found is not None:
        k, lists = found[3], None
    if rebuild_graph is None:
        rebuild_graph = setting["rebuild_graph"] if found is None else found[4]
    walks = seconds = None
    if aware_pipeline:
        select_scales = scales.resolve(select_scales, setting["scales_up_to"], distinct,
                                       found is None)
        if select_scales and found is None:
            started = time.perf_counter()
            stride = (probe["probe_stride"] if probe is not None
                      else -(-distinct // setting["probe"][0]))
            # Its lists (at stride 1, the first iteration's) replace the probe's.
            walks, lists = scales.plan(points, given, k, sigma_n, stride, shift_normals)
            seconds = time.perf_counter() - started
    return Plan(k, bool(rebuild_graph), select_scales, probe, noise, found, walks,
                lists, seconds, iterations, None if found is None else preset)


def _light(points, given, layout, iterations, rebuild_graph):
    """The edges route of :data:`LIGHT`, or None where it does not apply."""
    fast = PRESETS["fast"]
    _, probe, _ = aware.choose_k(points, given, *fast["probe"])
    if probe["ratio"] > LIGHT["up_to"]:
        return None
    noise = aware.noise_sigma(points, given, probe)
    found = layout(noise, "fast")
    if found is None:
        return None
    probe["coarse"] = None
    k = edges.list_length(probe)
    return Plan(found[3], bool(found[4] if rebuild_graph is None else rebuild_graph),
                False, probe, noise, found, None, None, None,
                fast["iterations"] if iterations is None else iterations, "fast",
                {"k": k, "radius": float(edges.reach(probe, k))})
