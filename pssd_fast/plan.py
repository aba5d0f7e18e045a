"""The run plan: which route a run takes and at which sizes, decided in one place for
:func:`pssd_fast.denoise`, :func:`pssd_fast.tiled.denoise` and
:func:`pssd_fast.tiled.denoise_file` (docs/ALGORITHM.md, "Routes").

The routes of the feature-aware pipeline: ``"cells"`` (the iterations run on the means of grid
cells sized by the noise, the points are moved onto their fits last; where the noise spans
several point spacings), ``"points"`` (the iterations run on the points, each fitted over its
``k`` nearest) and ``"walks"`` (on the points, each fitted over its own number of neighbours,
``select_scales``). The paper's pipeline and the baselines always run on the points.
"""
import math
import time
from dataclasses import dataclass
from typing import Callable, Optional

from .pipelines import aware, coarse, scales

#: Presets: the pipeline of the robust method and where ``k``, ``lam``, ``iterations`` and
#: ``rebuild_graph`` (on the input; on cell means see ``pssd_fast.pipelines.coarse.COARSE``)
#: come from when not given, and the most points and the neighbours of the noise probe
#: (``k=None``: chosen from the estimated noise, see ``pssd_fast.pipelines.aware.AUTO_K``, or
#: the coarse-to-fine route of ``pssd_fast.pipelines.coarse``; ``without_cells_k``: the ``k``
#: where that route finds no cells; ``scales_up_to``: the largest cloud whose points the
#: walks of ``select_scales=None`` take). "default" and "fast" run the feature-aware pipeline
#: (docs/DECISIONS.md, "Beyond the paper" and "Scan sizes"); "paper" is the paper's
#: formulation.
PRESETS = {
    "default": {"pipeline": "aware", "k": None, "lam": None, "iterations": 4,
                "rebuild_graph": True, "probe": (100_000, 96), "scales_up_to": 50_000},
    "fast": {"pipeline": "aware", "k": None, "lam": None, "iterations": 2,
             "rebuild_graph": False, "probe": (5_000, 32), "without_cells_k": 48,
             "scales_up_to": 0},
    "paper": {"pipeline": "paper", "k": 25, "lam": 0.5, "iterations": 2, "rebuild_graph": True,
              "probe": (100_000, 96), "scales_up_to": 0},
}


@dataclass
class Plan:
    """What a run does, decided before its iterations.

    Attributes
    ----------
    route : {"cells", "points", "walks"}
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
        ``k`` and ``rebuild_graph`` (:func:`pssd_fast.pipelines.coarse.layout`).
    walks : ScalePlan or None
        What the walks share (walks route; :func:`pssd_fast.pipelines.scales.plan`).
    lists : ListScales or None
        Lists the first iteration can take over (the probe's or the walks' plan's).
    walks_seconds : float or None
        What planning the walks took.
    """

    route: str
    k: int
    rebuild_graph: bool
    select_scales: Optional[bool]
    probe: Optional[dict]
    noise: Optional[float]
    layout: Optional[tuple]
    walks: Optional[scales.ScalePlan]
    lists: object
    walks_seconds: Optional[float]

    def walks_record(self):
        """What the walks' plan set, for ``stats["scales"]``; None off the walks route."""
        if self.walks is None:
            return None
        return {"lengths": self.walks.lengths.tolist(), "first": self.walks.first,
                "noise": math.sqrt(self.walks.noise2), "seconds": self.walks_seconds}

    def describe(self):
        """The plan for ``stats["plan"]`` (JSON-serialisable)."""
        return {"route": self.route, "k": self.k, "rebuild_graph": self.rebuild_graph,
                "select_scales": self.select_scales}


def make(points, given, preset, *, distinct, layout: Callable, k=None, aware_pipeline=True,
         rebuild_graph=None, select_scales=None, sigma_n=None, shift_normals=True):
    """The :class:`Plan` of a run on ``points`` (Morton order; a ``(n, 3)`` array or what
    offers ``shape`` and ``[::step]`` as one, :class:`pssd_fast.ondisk.Buckets`).

    Parameters
    ----------
    points, given
        The distinct positions, relative to the centre, and the caller's normals or None.
    preset : str
        A key of :data:`PRESETS`.
    distinct : int
        The number of distinct positions.
    layout : callable
        ``layout(noise)``: :func:`pssd_fast.pipelines.coarse.layout` of the cloud at that
        noise (its grouping first), or None.
    k : int or None
        The caller's ``k`` (None: from the noise probe where the preset has none).
    aware_pipeline : bool
        Whether the run takes the feature-aware pipeline (its routes and ``select_scales``).
    rebuild_graph, select_scales : bool or None
        The caller's (None: the preset and the cloud decide).
    sigma_n, shift_normals
        The feature-aware pipeline's, for the walks' plan.
    """
    setting = PRESETS[preset]
    probe = lists = noise = found = None
    if k is None and setting["k"] is None:
        k, probe, lists = aware.choose_k(points, given, *setting["probe"])
        probe["coarse"] = None
        if aware_pipeline and probe["ratio"] >= coarse.COARSE[preset]["min_ratio"]:
            noise = aware.noise_sigma(points, given, probe)
            found = layout(noise)
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
    route = "points" if found is None else "cells"
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
            route = "walks"
    return Plan(route, k, bool(rebuild_graph), select_scales, probe, noise, found, walks,
                lists, seconds)
