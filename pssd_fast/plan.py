"""What a run does, decided once before its first step, for :func:`pssd_fast.denoise`,
:func:`pssd_fast.tiled.denoise` and :func:`pssd_fast.tiled.denoise_file` alike
(docs/ALGORITHM.md, "The plan").

The default method (presets "default" and "fast") reads the noise and the spacing from a probe
(:mod:`pssd_fast.noise`) and sizes from them its cells, its lists and the radius every step
reads (:mod:`pssd_fast.method`). The paper's pipeline and the baselines iterate on the points
over lists of ``k`` nearest neighbours.
"""
import time
from dataclasses import dataclass, field
from typing import NamedTuple, Optional

import numpy as np

from . import method, noise
from ._validation import warn
from .noise import Noise, probe

#: Presets: the pipeline of the robust method; for the default method whether it refines
#: the points that fail its test ("fast" is the default method without that pass); for the
#: paper's pipeline its ``k``, ``lam``, iterations and ``rebuild_graph``; and the baselines'
#: (``"k": "probe"``: from the noise probe, :data:`BASELINE_K`; an integer: that ``k``, at most
#: the distinct positions less one). Under "paper" the baselines take the paper's (its ``k``
#: exactly: a smaller cloud is refused).
PRESETS = {
    "default": {"pipeline": "default", "refine": True,
                "baselines": {"iterations": 4, "k": "probe", "rebuild_graph": True}},
    "fast": {"pipeline": "default", "refine": False,
             "baselines": {"iterations": 2, "k": 48, "rebuild_graph": False}},
    "paper": {"pipeline": "paper", "iterations": 2, "k": 25, "lam": 0.5, "rebuild_graph": True},
}

#: The baselines' ``k`` under "default", from the noise probe (:func:`pssd_fast.noise.probe`):
#: linear in ``log(sigma / spacing)`` and ``log k`` between the anchors ``(sigma / spacing,
#: k)``, held at the end values outside them, at least 10. Each anchor is what the probe reads
#: on the generated CAD part (100,000 points) at 0.25%, 0.5% and 1% noise, and the smallest
#: ``k`` of the grid tried there (48, 64, 96, 128, 160, 192) that beat both CGAL peers on both
#: errors (docs/DECISIONS.md, "`k` from the data").
BASELINE_K = ((0.837, 64), (1.687, 96), (3.236, 160))


#: The largest share of a cloud one fit may read before a run warns (:func:`_small`). The CAD
#: part, the sphere and the cube at 0.25% noise, lists of 80: at a share of a quarter and
#: more (300 points or fewer) the part and the cube ended 1.3 to 11 times as far from the
#: surface as their input; at a sixth (500 points) 0.34 to 1.03 times, at a twelfth 0.28 to
#: 0.64 times.
SMALL = 1 / 4
#: The fewest steps of float64 that must span the points' spacing, and their noise, at the
#: cloud's far corner (:func:`resolved`): below about 20 the CAD part's error grew with a point
#: far away (1e13 times its size: 7 steps, 24% farther from the truth); at 58 steps it was
#: unchanged. Autzen's noise is 0.08 of its spacing: a row 1e15 feet away left 2.7 steps
#: across its noise, 35 across its spacing, and moved its other points' coordinates by 0.23
#: noise widths on average.
RESOLUTION = 20
#: A noise below this share of the spacing counts as this share: the cloud is clean, and its
#: coordinates need not resolve what noise it has.
CLEAN = 0.01


def iterating(preset):
    """The iterations, ``k`` and ``rebuild_graph`` of the paper's pipeline or of a baseline
    under ``preset`` (the paper's pipeline runs under "paper" only)."""
    return PRESETS[preset] if preset == "paper" else PRESETS[preset]["baselines"]


class Refine(NamedTuple):
    """The failing points' own iterations: ``k`` points within ``bound`` of each, ``iterations``
    of them (the default method's :data:`pssd_fast.method.REFINE`)."""

    k: int
    bound: float
    iterations: int


@dataclass(frozen=True)
class Plan:
    """What a run does. Frozen: built by :func:`make` before the first step, never changed.

    Attributes
    ----------
    pipeline : str
        ``"default"`` (the default method), ``"paper"``, ``"bilateral"`` or ``"mls"``.
    iterations : int
        The default method's iterations on the cell means; the others' on the points.
    k : int
        The default method's list length on the cell means; the others' ``k``.
    noise : Noise or None
        The default method's probe.
    edge : float or None
        The cells' edge (default method).
    bound : float or None
        How far the lists on the cell means reach (default method).
    low : (3,) ndarray or None
        The grid's corner: the cloud's low corner (default method).
    refine : Refine or None
        The failing points' own iterations; None: no refinement ("fast").
    own_noise : bool
        Whether the test reads each point's noise from its own fit over those lists (they span
        at least ``TEST["span"]`` noise widths of the probe's noise, or of ``own_sigma``),
        else the probe's ``sigma``.
    own_sigma : float or None
        The noise as the refinement's own fits read it on the probe's sample, where that
        reading decides ``own_noise`` (:func:`pssd_fast.method.own_reading_decides`,
        :func:`pssd_fast.noise.own_sigma`); else None.
    rebuild_graph : bool
        The paper's pipeline and the baselines: whether each iteration queries its lists
        anew.
    probe : dict or None
        The baselines' noise probe behind a ``k`` chosen from the data, or the seconds the
        default method's probe and own reading took (``seconds``); else None.
    """

    pipeline: str
    iterations: int
    k: int
    noise: Optional[Noise] = None
    edge: Optional[float] = None
    bound: Optional[float] = None
    low: Optional[np.ndarray] = field(default=None, compare=False)
    refine: Optional[Refine] = None
    own_noise: bool = False
    own_sigma: Optional[float] = None
    rebuild_graph: bool = False
    probe: Optional[dict] = None

    def describe(self):
        """The plan for ``stats["plan"]`` (JSON-serialisable)."""
        if self.pipeline != "default":
            return {"method": self.pipeline, "k": self.k, "iterations": self.iterations,
                    "rebuild_graph": self.rebuild_graph}
        return {"method": "default", "iterations": self.iterations, "k": self.k,
                "cell_edge": self.edge, "bound": self.bound, "noise": self.noise.record(),
                "refine": None if self.refine is None else
                {"k": self.refine.k, "bound": self.refine.bound,
                 "iterations": self.refine.iterations, "own_noise": self.own_noise,
                 "own_sigma": self.own_sigma}}


def make(points, preset, pipeline, *, distinct, low, k=None, iterations=None,
         rebuild_graph=None):
    """The :class:`Plan` of a run on ``points`` (distinct positions in Morton order, relative
    to the run's centre; or what offers ``shape`` and ``[::step]`` as one, out of core).

    Parameters
    ----------
    points
        The positions.
    preset : str
        A key of :data:`PRESETS`.
    pipeline : str
        ``"default"``, ``"paper"``, ``"bilateral"`` or ``"mls"``.
    distinct : int
        The number of distinct positions.
    low : (3,) ndarray
        The cloud's low corner, relative to the centre (the default method's grid).
    k, iterations, rebuild_graph
        The caller's, or None (the preset's; ``k`` of the default method and of the baselines
        under "default" from the noise probe).
    """
    if pipeline == "default":
        return _small(_default(points, PRESETS[preset], distinct, low, k, iterations),
                      distinct)
    setting = iterating(preset)
    iterations = setting["iterations"] if iterations is None else iterations
    probed = None
    if k is None and setting["k"] == "probe":
        k, probed = _baseline_k(points, distinct, low)
    elif k is None and preset == "paper":
        k = setting["k"]  # the paper's, never cut to the cloud
        if distinct < k + 1:
            raise ValueError(f"the cloud has {distinct} distinct "
                             f"position{'s' * (distinct != 1)}; preset 'paper' "
                             f"uses k = {k} neighbours and needs at least {k + 1}; pass a "
                             "smaller k")
    elif k is None:
        k = min(setting["k"], distinct - 1)
    rebuild = setting["rebuild_graph"] if rebuild_graph is None else rebuild_graph
    return _small(Plan(pipeline, iterations, k, rebuild_graph=bool(rebuild), probe=probed),
                  distinct)


def _small(plan, distinct):
    """``plan``, with a :class:`pssd_fast.DenoiseWarning` where each fit reads more than
    :data:`SMALL` of the cloud: ``k`` of its ``distinct`` points, or (the default method) ``k``
    cell means of cells wider than the spacing."""
    cells = 1.0 if plan.edge is None else max(1.0, (plan.edge / plan.noise.spacing) ** 2)
    share = plan.k * cells / distinct
    if share > SMALL:
        warn(
            f"the cloud has {distinct:,} distinct points and each fit reads "
            f"{'all' if share >= 1.0 else f'{share:.0%}'} of it: "
            f"fits over so much of a surface are bent by its shape, and the result may end "
            f"farther from the surface than the input (the CAD part at 300 points and 0.25% "
            f"noise: 1.45 times as far; at 1,000 points 0.64); denoise larger clouds")
    return plan


def resolved(found, low):
    """``found`` (the probe's :class:`pssd_fast.noise.Noise`) where the positions, relative to
    the centre of the bounding box whose ``low`` corner this is, resolve its spacing and its
    noise (:func:`check_resolution`)."""
    check_resolution(found.spacing, float(np.abs(np.asarray(low, np.float64)).max()),
                     found.sigma)
    return found


def check_positions(points, spacing):
    """:func:`check_resolution` of a run whose plan read no noise (the paper's pipeline, a
    baseline given its ``k``), at the ``spacing`` its lists read: the probe reads the noise
    only where the positions ``points`` (relative to the run's centre) could fail to hold it,
    so that the check costs no run a probe but those with a point far from the rest."""
    reach = float(np.abs(points).max())
    check_resolution(spacing, reach)
    if spacing < RESOLUTION / CLEAN * float(np.spacing(reach)):
        check_resolution(spacing, reach, probe(points).sigma)


def check_resolution(spacing, reach, noise=None):
    """ValueError where positions as far as ``reach`` from the run's centre resolve the
    points' ``spacing``, or their ``noise`` where given and smaller (at least :data:`CLEAN`
    times the spacing), in fewer than :data:`RESOLUTION` steps of float64: points far from the
    rest (a stray return, a row at the origin) stretch the bounding box until the others'
    coordinates lose the digits that tell them apart, or that hold their noise."""
    step = float(np.spacing(reach))
    what, scale = "spacing", spacing
    if noise is not None and max(noise, CLEAN * spacing) < spacing:
        what, scale = "noise", max(noise, CLEAN * spacing)
    if not scale >= RESOLUTION * step:
        reaches = (f"the cloud reaches {reach:.3g} along an axis from the centre of its "
                   f"bounding box, where float64 resolves steps of {step:.3g}")
        if spacing > 0.0:
            noisy = "" if noise is None else f" with a noise of about {noise:.3g}"
            problem = (f"the points lie about {spacing:.3g} apart{noisy}, but {reaches}: "
                       f"fewer than {RESOLUTION} across the {what}")
        else:  # the positions relative to the centre no longer differ at all
            problem = f"{reaches}, and the points' positions no longer tell them apart"
        raise ValueError(f"{problem}. Remove the points far from the rest (a stray return, a "
                         f"row at the origin) and run again")


def _baseline_k(points, distinct, low):
    """The baselines' ``k`` from the noise probe (:data:`BASELINE_K`), and the probe's record
    for ``stats["auto_k"]``."""
    started = time.perf_counter()
    found = resolved(probe(points), low)
    ratio = found.sigma / found.spacing if found.spacing > 0.0 else 0.0
    logs = np.log(np.array(BASELINE_K, dtype=float))
    k = int(round(np.exp(np.interp(np.log(max(ratio, 1e-12)), logs[:, 0], logs[:, 1]))))
    k = max(min(k, distinct - 1), min(10, distinct - 1))
    return k, {"k": k, "noise": found.sigma, "spacing": found.spacing, "ratio": ratio,
               "seconds": time.perf_counter() - started}


def _default(points, setting, distinct, low, k, iterations):
    """The default method's plan: its probe and the sizes of its steps (``k``: the caller's
    list length on the means, or None)."""
    started = time.perf_counter()
    taken = noise.sample(points)
    found = resolved(probe(points, taken), low)
    edge = method.cell_edge(found.sigma, found.spacing)
    if k is None:
        k = min(method.list_length(found.sigma, found.spacing, edge), distinct - 1)
    bound = method.list_bound(k, found.spacing, edge)
    refine = None
    own, own_sigma = False, None
    if setting["refine"]:
        k_r = min(method.list_length(found.sigma, found.spacing, 0.0, method.REFINE["radius"],
                                     method.REFINE["k"]), distinct - 1)
        refine = Refine(k_r, method.list_bound(k_r, found.spacing, 0.0),
                        method.REFINE["iterations"])
        own = method.own_lists_span(k_r, found.spacing, found.sigma)
        if method.own_reading_decides(k_r, found.spacing, found.sigma):
            # The probe reads thin and curved parts' shape as noise: the own fits' reading
            # decides (docs/ALGORITHM.md, "The test and the refinement").
            own_sigma = noise.own_sigma(points, taken, k_r, refine.bound,
                                        method.list_radius(k_r, found.spacing))
            own = method.own_lists_span(k_r, found.spacing, own_sigma)
    return Plan("default", method.ITERATIONS if iterations is None else iterations, k,
                noise=found, edge=edge, bound=bound, low=np.asarray(low, np.float64),
                refine=refine, own_noise=own, own_sigma=own_sigma,
                probe={"seconds": time.perf_counter() - started})
