"""A run once its parameters are resolved: the iterations of a pipeline's step, and what it
returns in the caller's order. :func:`pssd_fast.denoise` and the tiled runs
(:mod:`pssd_fast.tiled`) share it, so that both give the same bits and the same ``stats``."""
import math
import time
from dataclasses import dataclass, field, fields
from typing import Callable, NamedTuple, Optional

import numpy as np

from . import core
from ._threads import threads
from ._validation import MIN_K, check_int
from .graph import curve_order, knn_graph, refresh_graph
from .parameters import BY_NAME
from .pipelines import STEPS
from .pipelines.normals import estimated_normals
from .plan import check_positions
from .progress import Clock
from .stats import Iteration, Stats


@dataclass(frozen=True, eq=False)
class DenoiseResult:
    """Output of :func:`pssd_fast.denoise`; arrays are in the caller's point order and float
    dtype.

    Results compare by identity; compare their arrays with :func:`numpy.array_equal`. A result
    pickles (a worker process can return it) with ``likelihood`` and ``feature_intensity``
    computed first where they were not yet read.

    Attributes
    ----------
    points : (n, 3) ndarray
        Denoised positions.
    normals : (n, 3) ndarray
        Robust method: the filtered unit normals ``n*_i`` of the last iteration. Baselines: the
        normals the last iteration used.
    likelihood : (n,) ndarray or None
        Sampling likelihood ``l_i`` of the last iteration (robust method only; presets
        "default" and "fast" compute it from the RMS residual of the last fit of each point's
        cell mean). Under "default" and "fast" computed when first read, unless the run was
        asked for it (``extras=True``): milliseconds (``python -m benchmarks.fields``).
    feature_intensity : (n,) ndarray or None
        Feature intensity ``s_i`` of the last iteration (robust method only; presets "default"
        and "fast": the paper's voting over the cell means). Under "default" and "fast"
        computed when first read, unless ``extras=True``: a voting over the cell means, about
        a quarter of the default's run time (``python -m benchmarks.fields``).
    displacement : (n,) ndarray
        ``|p_noisy - p_denoised|``, the quantity of the paper's Table 1 and Fig. 8.
    held : (n,) bool ndarray
        Where a move of the point was refused and the point kept its place instead: a move
        that was not finite, or longer than the radius of the neighbour list behind it (the
        paper's pipeline and the baselines: in any iteration; the default method: in the move
        onto the cell means' fits or in the refinement). ``stats["held_points"]`` counts them
        (docs/DECISIONS.md, "No point flung").
    outlier_score : (n,) ndarray or None
        With ``remove_outliers=True``: :func:`pssd_fast.outlier_score` of the input points
        (before any iteration, ``k = 64``) that the run computed to drop those above 1. Else
        None: the run makes no outlier query and keeps no copy of the input for one;
        ``pssd_fast.outlier_score(points)`` gives it (docs/DECISIONS.md, "The outlier score
        on request").
    kept : (n,) int64 ndarray
        Rows of the input that the other arrays hold, in increasing order: every row, or with
        ``remove_outliers=True`` those scoring at most 1 (so ``points[kept]`` is what was
        denoised and ``outlier_score`` has one value per kept row).
    stats : Stats
        What the run chose and did (:class:`pssd_fast.Stats`): its settings, the plan, the
        probe's noise, the points held, one :class:`pssd_fast.stats.Iteration` per iteration
        (per-stage wall times, fallback counts, the derived scales) and the call's
        ``total_seconds``; with a ``classification``, the classes run (``classes``). Read as
        attributes or as a mapping (``stats["k"]``); ``stats.to_dict()`` for JSON.
    """

    points: np.ndarray
    normals: np.ndarray
    likelihood: Optional[np.ndarray] = field(repr=False)
    feature_intensity: Optional[np.ndarray] = field(repr=False)
    displacement: np.ndarray
    held: np.ndarray
    outlier_score: Optional[np.ndarray]
    kept: np.ndarray
    stats: Stats = field(repr=False)

    def __getattribute__(self, name):
        value = object.__getattribute__(self, name)
        if type(value) is Deferred:
            value = value.compute()
            object.__setattr__(self, name, value)
        return value

    def __getstate__(self):
        # Pickled (for a worker process to return it) with its deferred fields computed: what
        # they compute from does not travel.
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Deferred:
    """A field of a :class:`DenoiseResult` computed when it is first read: ``compute()`` gives
    it."""

    def __init__(self, compute):
        self.compute = compute


def stored(result, name):
    """A :class:`DenoiseResult`'s field ``name`` as it is held: its value, or a
    :class:`Deferred` not read yet."""
    return object.__getattribute__(result, name)


def outlier_scores(points, n_jobs, k=core.OUTLIER_K):
    """:func:`pssd_fast.outlier_score` of valid ``points`` (float32 or float64), in their
    dtype; ValueError where they are fewer than the score's lists need."""
    k = check_int(k, "k", minimum=MIN_K)
    if points.shape[0] < k + 1:
        raise ValueError(f"the outlier score reads each point's {k} nearest points and needs "
                         f"at least {k + 1}; the cloud has {points.shape[0]} "
                         f"(pssd_fast.outlier_score takes a smaller k; remove_outliers does not "
                         f"read denoise's k)")
    with threads(n_jobs):
        pts = points.astype(np.float64, copy=False)
        order = curve_order(pts)
        pts = pts[order]
        score = np.empty(pts.shape[0])
        score[order] = core.outlier_score(pts, knn_graph(pts, k))
    return score.astype(points.dtype, copy=False)


@dataclass
class Request:
    """What a run was asked, once resolved: the settings its iterations, its result and its
    ``stats`` read.

    Attributes
    ----------
    method, preset, pipeline : str
        The method, the preset and the pipeline the two choose (``"default"``, ``"paper"``,
        ``"bilateral"`` or ``"mls"``).
    lam : float or None
        The paper's pipeline's ``lambda`` (else None).
    params : dict
        The method's parameters (:data:`pssd_fast.parameters.METHOD_DEFAULTS`), checked.
    orient : str, (3,) ndarray or None
        The first iteration's sign of the normals.
    centre : (3,) ndarray
        What the run's positions are relative to (the input's bounding-box centre).
    report : callable or None
        The progress callback (:func:`pssd_fast.progress.reporter`).
    started : float
        ``time.perf_counter()`` when the run started.
    extras : bool
        Whether the default method computes the likelihood and the feature intensity during
        the run (else when the result's fields are first read).
    """

    method: str
    preset: str
    pipeline: str
    lam: Optional[float]
    params: dict
    orient: object
    centre: np.ndarray
    report: Optional[Callable]
    started: float
    extras: bool = True

    @property
    def step(self):
        """The step of the paper's pipeline or a baseline (:data:`pssd_fast.pipelines.STEPS`)."""
        return STEPS[self.pipeline]


class Iterated(NamedTuple):
    """The outputs of :func:`iterate`, in its points' order: the moved ``points``, the last
    iteration's ``normals`` and ``(likelihood, feature intensity)`` (arrays, functions that
    compute them, or None), one record per iteration, and the mask of the points ``held`` in
    place in at least one of them."""

    points: np.ndarray
    normals: np.ndarray
    extra: Optional[tuple]
    records: list
    held: np.ndarray


def iterate(current, given, plan, request):
    """The ``plan.iterations`` of ``request``'s pipeline step on the points ``current``
    (Morton order, relative to ``request.centre``): an :class:`Iterated`. The paper's pipeline
    and the baselines.

    ``given``: the caller's normals in that order, or None. The plan gives ``k`` and
    ``rebuild_graph``.
    """
    k, iterations, rebuild_graph = plan.k, plan.iterations, plan.rebuild_graph
    params, step, centre = request.params, request.step, request.centre
    records = []
    out_normals = graph = extra = held = None
    for iteration in range(iterations):
        clock = Clock(request.report, iteration, iterations)
        if graph is None or rebuild_graph:
            graph = None  # the last lists go before the new ones are built, not after
            graph = clock.run("neighbors", knn_graph, current, k, False)
            if iteration == 0:
                # On a surface k points cover pi r^2 = k s^2; the median ignores stray points.
                check_positions(current,
                                float(np.median(graph.list_radius())) * math.sqrt(math.pi / k))
        else:
            graph = clock.run("neighbors", refresh_graph, graph, current)
        if given is not None:
            nrm, degenerate = clock.run("normals", _given_normals, given)
        else:
            first = request.orient if out_normals is None else None
            nrm, degenerate = clock.run("normals", estimated_normals, current, graph,
                                        out_normals, first, centre, None)
        moved, out_normals, extra, record, held_now = step(
            current, nrm, graph, request.lam, params, clock, iteration == iterations - 1)
        held = held_now if held is None else held | held_now
        record["degenerate_normals"] = int(degenerate.sum())
        record["mean_step"] = float(np.linalg.norm(moved - current, axis=1).mean())
        records.append(record)
        current = moved
        if not params["keep_normals"]:
            given = None
    return Iterated(current, out_normals, extra, records, held)


class Input(NamedTuple):
    """The input rows a run denoised: ``points`` (float64), the caller's ``dtype``, and their
    Morton order with the rows of their distinct positions (``order``, ``groups``:
    :func:`pssd_fast.duplicates.ordered`)."""

    points: np.ndarray
    dtype: np.dtype
    order: np.ndarray
    groups: Optional[np.ndarray]


def result(rows, done, centre, kept, score, stats):
    """The :class:`DenoiseResult` of a run on the input ``rows`` (:class:`Input`), whose
    outputs ``done`` (:class:`Iterated`) are in the order of ``rows.order`` and
    ``rows.groups``, relative to ``centre``; ``score``: the outlier scores of the ``kept``
    rows, or None."""
    pts, dtype, order, groups = rows
    shift = _to_caller_order(done.points, order, groups)
    points = shift + centre
    displacement = np.linalg.norm(shift - (pts - centre), axis=1)
    if groups is not None:
        # A copy's move, from its own input position, as tiled.denoise_file computes it.
        copy = np.ones(pts.shape[0], np.bool_)
        copy[order] = False
        displacement[copy] = np.linalg.norm(points[copy] - pts[copy], axis=1)

    def caller(values):
        return _to_caller_order(values, order, groups).astype(dtype, copy=False)

    lik, feat = (None, None) if done.extra is None else (
        Deferred(lambda get=x: caller(get())) if callable(x) else caller(x) for x in done.extra)
    return DenoiseResult(
        points=points.astype(dtype, copy=False),
        normals=_to_caller_order(done.normals, order, groups).astype(dtype, copy=False),
        likelihood=lik,
        feature_intensity=feat,
        displacement=displacement.astype(dtype, copy=False),
        held=_to_caller_order(done.held, order, groups),
        outlier_score=score,
        kept=kept,
        stats=stats,
    )


def stats(request, plan, n, distinct, n_threads, records, held, outliers=None, tiles=None):
    """A run's :class:`~pssd_fast.stats.Stats` for ``n`` points at ``distinct`` positions,
    ``held`` of them held in place; ``records``: one dict per iteration (the fields of an
    :class:`~pssd_fast.stats.Iteration`); ``outliers``: what ``remove_outliers`` did, or
    None; ``tiles``: a tiled run's tiles."""
    orient = request.orient
    return Stats(
        method=request.method,
        n_points=n,
        duplicates=n - distinct,
        k=plan.k,
        lam=request.lam,
        preset=request.preset,
        pipeline=request.pipeline,
        plan=plan.describe(),
        auto_k=plan.probe,
        noise=plan.noise.sigma if plan.noise is not None else (
            None if plan.probe is None else plan.probe["noise"]),
        rebuild_graph=plan.rebuild_graph,
        orient=orient if orient is None or isinstance(orient, str) else orient.tolist(),
        outliers=outliers,
        n_iterations=plan.iterations,
        held_points=held,
        # None in the checked parameters is a choice left to the library; the method's
        # parameters of another pipeline (the paper's under "default") are not the run's.
        params={name: "auto" if value is None else value
                for name, value in request.params.items()
                if request.pipeline in (BY_NAME[name].pipelines or (request.pipeline,))},
        n_jobs=n_threads,
        iterations=tuple(Iteration(**record) for record in records),
        tiles=tiles,
        total_seconds=time.perf_counter() - request.started,
    )


class FewPositions(ValueError):
    """A cloud of enough points at too few distinct positions (:func:`check_distinct`); a
    class the library chose to denoise is left as it is instead (:mod:`pssd_fast.classes`).
    ``distinct``: the positions."""

    def __init__(self, message, distinct):
        super().__init__(message)
        self.distinct = distinct


def check_distinct(distinct, n, k):
    """``distinct``, the positions among ``n`` points, checked against ``k`` (None: the
    preset chooses it); :class:`FewPositions` where too few."""
    if distinct < n and distinct < (MIN_K if k is None else k) + 1:
        raise FewPositions(f"the cloud has {n} points but only {distinct} distinct "
                           f"position{'s' * (distinct != 1)}; "
                           f"denoising needs at least {(MIN_K if k is None else k) + 1}"
                           + ("" if k is None else f" for k = {k} (lower k)"), distinct)
    return distinct


def _to_caller_order(values, order, groups=None):
    """``values`` (rows in Morton order ``order``; with ``groups``, those of the distinct
    positions, :func:`pssd_fast.duplicates.ordered`) back in the caller's order."""
    return core.caller_order(values, order) if groups is None else values[groups]


def _given_normals(normals):
    """The caller's normals, with no degenerate neighbourhood to report."""
    return normals, np.zeros(normals.shape[0], np.bool_)
