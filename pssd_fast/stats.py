"""What a run reports (``DenoiseResult.stats``): a frozen :class:`Stats` with one
:class:`Iteration` per iteration, built once when the run ends.

Both read as attributes (``stats.k``) and as the read-only mappings earlier versions returned
(``stats["k"]``, ``stats.get("classes")``); ``to_dict()`` gives plain dicts and lists for
JSON."""
import dataclasses
import time
from collections.abc import Mapping
from typing import Any, Optional, Tuple


class _Fields(Mapping):
    """A frozen dataclass read as a mapping of its fields; a field whose default is None and
    which is None is left out (a run that has no such part)."""

    def _names(self):
        return [f.name for f in dataclasses.fields(self)
                if not (f.default is None and getattr(self, f.name) is None)]

    def __getitem__(self, name):
        if name not in self._names():
            raise KeyError(name)
        return getattr(self, name)

    def __iter__(self):
        return iter(self._names())

    def __len__(self):
        return len(self._names())

    def to_dict(self):
        """The fields as plain dicts and lists (JSON-serialisable)."""
        return {name: _plain(self[name]) for name in self}


def _plain(value):
    """``value`` with every :class:`_Fields` inside it as a dict and tuples as lists."""
    if isinstance(value, _Fields):
        return value.to_dict()
    if isinstance(value, Mapping):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


@dataclasses.dataclass(frozen=True, eq=False)
class Iteration(_Fields):
    """One iteration's record. ``times``: wall seconds per stage; the others as the pipeline
    reports them (None, and left out of the mapping, where it does not):

    ``held_points`` (points left in place: a step not finite or longer than its list's
    radius), ``mean_residual``, ``fit_degree`` (counts of each fit's degree), ``h`` (the MLS
    bandwidth), ``mean_spacing`` and ``region_radius`` (the paper's scales),
    ``region_size_mean`` and ``region_size_max`` (its grown regions), ``degenerate_normals``,
    ``mean_step`` (paper and baselines); ``cells`` (the means iterated) and ``refined`` (the
    points the test sent to the refinement) in the default method's last iteration.
    """

    times: dict
    held_points: Optional[int] = None
    mean_residual: Optional[float] = None
    fit_degree: Optional[dict] = None
    h: Optional[float] = None
    mean_spacing: Optional[float] = None
    region_radius: Optional[float] = None
    region_size_mean: Optional[float] = None
    region_size_max: Optional[int] = None
    degenerate_normals: Optional[int] = None
    mean_step: Optional[float] = None
    cells: Optional[int] = None
    refined: Optional[int] = None


@dataclasses.dataclass(frozen=True, eq=False)
class Stats(_Fields):
    """A run's report (:class:`pssd_fast.DenoiseResult`'s ``stats``).

    Attributes
    ----------
    method : str
        "robust" (the default method and the paper's pipeline) or the baseline's name.
    n_points, duplicates : int
        Rows denoised, and those merged into another at their position
        (:mod:`pssd_fast.duplicates`).
    k : int
        The neighbour count the run used (the default method: the means' lists).
    lam : float or None
        The paper's ``lambda`` (None where the pipeline has none).
    preset, pipeline : str
        The preset asked for, and the pipeline it ran ("default", "paper", "bilateral",
        "mls").
    plan : dict
        What the run chose (docs/ALGORITHM.md, "The plan"): for the default method its
        ``iterations``, ``k``, ``cell_edge``, ``bound``, the probe's ``noise`` and the
        refinement's ``k``, ``bound``, ``iterations`` and ``own_noise``.
    auto_k : dict or None
        The noise probe behind the run's sizes (its seconds; the baselines' also its ``k``),
        or None where the caller gave ``k``.
    noise : float or None
        The noise ``sigma`` the probe read.
    rebuild_graph : bool or None
        Whether each iteration queried its lists anew (paper and baselines).
    orient : str, list or None
        The ``orient`` asked for.
    outliers : dict or None
        What ``remove_outliers`` did (its seconds and the rows removed).
    n_iterations, held_points : int
        Iterations, and points held in place (:attr:`pssd_fast.DenoiseResult.held`).
    params : dict
        The parameters of the pipeline that ran, as given ("auto": left to the library): the
        default method's under "default" and "fast", the paper's under "paper".
    n_jobs : int
        Threads the kernels ran on.
    iterations : tuple of Iteration
        One record per iteration.
    tiles : dict or None
        A tiled run's tiles: their ``count``, ``most_points``, the ``scheduler`` and
        ``threads`` that ran them; from a file, the seconds of each pass over it ``before``
        the iterations (binning it into buckets and tiles) and ``after`` them (the tiles'
        parts and the write). Not in the mapping otherwise.
    total_seconds : float
        Wall seconds of the call.
    displacement : dict or None
        A run from a file to a file (:func:`pssd_fast.tiled.denoise_file`): the largest
        (``max``) and the mean (``mean``) distance of the output's rows from the input's, in
        its units, before a LAS/LAZ output rounds the coordinates to its scale. Not in the
        mapping otherwise.
    classes : dict or None
        With a ``classification``: the codes denoised (or "all"), the points ``denoised`` and
        ``untouched``, the classes ``too_small`` and each run's :class:`Stats` (``runs``);
        the other fields are the largest class's run's, with ``n_points``, ``duplicates``,
        ``held_points`` and ``outliers`` summed over the runs. Not in the mapping otherwise.
    """

    method: str
    n_points: int
    duplicates: int
    k: int
    lam: Optional[float]
    preset: str
    pipeline: str
    plan: dict
    auto_k: Optional[dict]
    noise: Optional[float]
    rebuild_graph: Optional[bool]
    orient: Any
    outliers: Optional[dict]
    n_iterations: int
    held_points: int
    params: dict
    n_jobs: int
    iterations: Tuple[Iteration, ...]
    tiles: Optional[dict] = None
    total_seconds: float = 0.0
    classes: Optional[dict] = None
    displacement: Optional[dict] = None


def finished(stats, times, started):
    """``stats`` of a run from a file with the stages ``times`` added to its tiles' passes
    after the iterations (the file's write) and the call's ``total_seconds`` counted from
    ``started``."""
    tiles = {**stats.tiles, "after": {**stats.tiles["after"], **times}}
    return dataclasses.replace(stats, tiles=tiles, total_seconds=time.perf_counter() - started)
