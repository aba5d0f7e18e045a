"""A scale per point for the feature-aware pipeline (parameter ``select_scales``;
docs/ALGORITHM.md, "A scale per point"; docs/DECISIONS.md, "Sparse clouds").

Each point fits nested quadratics over prefixes of a list 4.5 times as long as the
pipeline's ``k`` and walks up from a first prefix while the wider list still fits; the noise
the walks test against and the prefix they start from come from a probe of the input, before
the iterations, so that every point's choice depends on its own list alone.
"""
from typing import NamedTuple

import numpy as np

from .. import core
from ..graph import knn_graph, truncate_graph
from ..pipelines.normals import estimated_normals
from ..pipelines.walks import SCALES

def resolve(select_scales, up_to, n, on_points):
    """Whether a run of ``n`` points selects scales: as given (True or False), or where
    ``select_scales`` is None (``"auto"``), on the points (``on_points``; not on cell means) of a
    cloud of at most ``up_to`` points (the preset's ``scales_up_to``; docs/DECISIONS.md, "A scale
    per point by default")."""
    if select_scales is None:
        return bool(on_points and n <= up_to)
    return select_scales


class ScalePlan(NamedTuple):
    """What the walks of every iteration share: the prefix ``lengths``, the column the first
    iteration starts from and the noise variance it tests against."""

    lengths: np.ndarray
    first: int
    noise2: float

    def at(self, iteration):
        """The plan of the walks of ``iteration`` (0 is the first)."""
        if iteration == 0:
            return self
        return self._replace(first=0, noise2=SCALES["later_noise"] * self.noise2)


def lengths(k, n):
    """The prefix lengths at ``k`` neighbours in a cloud of ``n`` points: :data:`SCALES`
    factors of ``k``, increasing, ``k`` among them."""
    low = min(SCALES["smallest"], k)
    wanted = np.round(np.array(SCALES["factors"]) * k).astype(np.int64)
    return np.unique(np.clip(wanted, low, n - 1))


def plan(points, given, k, sigma_n, stride, shift):
    """The :class:`ScalePlan` of a run at ``k`` from a probe of every ``stride``-th point, and
    the sample's lists, which at ``stride`` 1 are the first iteration's longest (else None).

    The sample's normals are the first iteration's: PCA over ``k / stride`` neighbours
    (shifted if ``shift``; or the caller's ``given``), filtered. The fits of
    :func:`pssd_fast.core.scale_fits` (with the thin-wall weights of :func:`fit`) run over the
    prefixes of the sample's lists that span the area of each length (``length / stride``
    neighbours). The first column is the shortest whose median radius is at least
    ``radius_over_noise`` times the noise at ``k`` (the square root of the median residual
    variance there); the noise variance is the median residual variance at that column. At
    ``stride`` 1 these are the first iteration's own fits.
    """
    n = points.shape[0]
    scales = lengths(k, n)
    sample = np.ascontiguousarray(points[::stride])
    m = sample.shape[0]
    low = min(SCALES["smallest"], m - 1)
    wanted = np.clip(np.round(scales / stride).astype(np.int64), low, m - 1)
    prefixes = np.unique(wanted)
    lists = knn_graph(sample, int(prefixes[-1]), False)
    k_sample = int(wanted[np.searchsorted(scales, k)])
    graph = truncate_graph(lists, sample, k_sample)
    if given is None:
        nrm, _ = estimated_normals(sample, graph, None, None, None,
                                          k_sample if shift else None)
    else:
        nrm = np.ascontiguousarray(given[::stride])
    filtered = core.filter_normals(sample, nrm, graph)
    coef, across = core.robust_fits(sample, filtered, graph, sigma_n)[3:]
    fits = core.scale_fits(sample, filtered, lists, prefixes, sigma_n, k_sample, coef, across)
    column = np.searchsorted(prefixes, wanted)
    with np.errstate(invalid="ignore"):
        variance = fits.variance()[:, column]
    noise = np.sqrt(_median(variance[:, int(np.searchsorted(scales, k))]))
    wide = np.flatnonzero(np.median(fits.radius[:, column], axis=0)
                          >= SCALES["radius_over_noise"] * noise)
    first = int(wide[0]) if wide.size else len(scales) - 1
    # A noise-free sample measures no variance: every test then passes.
    noise2 = max(_median(variance[:, first]), np.finfo(float).tiny)
    return ScalePlan(scales, first, noise2), lists if stride == 1 else None


def _median(values):
    """The median of the finite ``values``; 0 where there are none."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else 0.0
