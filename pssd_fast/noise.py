"""The noise probe: the standard deviation of a cloud's noise and its point spacing, read on an
evenly spread sample before the method's first step (docs/ALGORITHM.md, "The noise probe";
docs/DECISIONS.md, "One noise probe").

At each sample point the robust spread of its nearest neighbours about their local quadratic
is read for three list lengths (:func:`pssd_fast.core.local_noise`). What such a spread reads
depends on the list's radius against the noise: a list a few noise widths across cuts the
noise's tails off and reads too little; a long one on a curved, edged or thin surface reads its
shape as noise. The first is known exactly, from a noisy plane (:data:`CALIBRATION`); each
length's median reading is mapped back through it to a noise, and the least of the lengths
whose lists span at least ``min_ratio`` noise widths is taken: the shortest list that is wide
enough sees the least of the shape.
"""
import math
from functools import partial
from typing import NamedTuple

import numpy as np

from . import core
from ._validation import STRAY, surface_mean
from .graph import NeighborGraph, candidates, knn_graph, merge_candidates

#: ``points``: the most points the probe reads (a larger cloud: every ``s``-th point of its
#: Morton order; a sparser sample would read a smaller cloud's curvature as noise);
#: ``lengths``: the list lengths read; ``min_ratio``: the fewest noise widths a length's mean
#: list radius must span for its reading to count; ``stray``: a list reaching more than this
#: many times the median radius belongs to a point off the surface (a stray return, a
#: "no return" row at the origin) and is left out of the mean radius.
PROBE = {"points": 20_000, "lengths": (12, 24, 48), "min_ratio": 2.0, "stray": STRAY}

#: What each list length reads on a plane with Gaussian noise of standard deviation ``sigma``:
#: ``(mean list radius / sigma, median reading / sigma)``, from 80,000 uniformly random points
#: of the unit square at 14 noise levels (``python -m benchmarks.noise_probe --calibrate``
#: measures it again: within 3% of these rows at its seed; tests/test_noise.py checks a few).
CALIBRATION = {
    12: ((1.06, 0.1791), (1.3, 0.2172), (1.62, 0.2645), (2.02, 0.3178), (2.55, 0.3782),
         (3.29, 0.43), (4.32, 0.4709), (5.76, 0.4905), (7.78, 0.502), (10.6, 0.5079),
         (14.4, 0.5099), (19.7, 0.5113), (27, 0.5115), (37, 0.5121)),
    24: ((1.36, 0.3728), (1.69, 0.4477), (2.11, 0.5328), (2.67, 0.6173), (3.45, 0.6879),
         (4.55, 0.7346), (6.09, 0.7598), (8.24, 0.7736), (11.2, 0.7795), (15.3, 0.7821),
         (20.9, 0.784), (28.7, 0.7852), (39.2, 0.7856), (53.7, 0.7859)),
    48: ((1.74, 0.5496), (2.18, 0.6409), (2.77, 0.7287), (3.59, 0.8006), (4.74, 0.8496),
         (6.36, 0.8758), (8.62, 0.8887), (11.7, 0.8952), (16, 0.8983), (21.9, 0.8998),
         (30, 0.9006), (41.1, 0.901), (56.3, 0.9011), (77.1, 0.9013)),
}


#: What the refinement's own fits read of a known noise (:func:`own_sigma`): ``(list radius /
#: sigma, reading / sigma)``, from planes of 60,000 uniformly random points of the unit square
#: at 9 noise levels, the lists sized as the plan sizes them from the probe
#: (``python -m benchmarks.noise_probe --own`` measures it again, these rows at its seed).
OWN_CALIBRATION = ((1.92, 0.638), (2.25, 0.733), (2.49, 0.795), (2.8, 0.849), (3.12, 0.886),
                   (3.59, 0.936), (4.11, 0.934), (6.05, 0.949), (12, 0.966))
#: The most points :func:`own_sigma` reads (every ``s``-th point of the probe's sample), and
#: how many of their lists at a time.
OWN_POINTS = 4000
OWN_BLOCK = 4096


class Noise(NamedTuple):
    """What the probe measured.

    Attributes
    ----------
    sigma : float
        The noise's standard deviation, in the cloud's units (0 on an exact sample).
    spacing : float
        The point spacing: the side of the area each point covers on the surface.
    stride : int
        Every ``stride``-th point of the Morton order was read.
    readings : dict
        For each list length: its median reading, its mean list radius (of the sample) and the
        noise it maps to.
    """

    sigma: float
    spacing: float
    stride: int
    readings: dict

    def record(self):
        """The probe for ``stats["plan"]`` (JSON-serialisable)."""
        return {"sigma": self.sigma, "spacing": self.spacing, "stride": self.stride,
                "readings": {str(k): v for k, v in self.readings.items()}}


def sample(points):
    """The probe's sample of ``points`` (distinct positions in Morton order; a ``(n, 3)``
    array or what offers ``shape`` and ``[::step]`` as one): every ``stride``-th point, at
    most ``PROBE["points"]``; ``(sample, stride)``."""
    stride = -(-points.shape[0] // PROBE["points"])
    return np.ascontiguousarray(points[::stride], dtype=np.float64), stride


def probe(points, taken=None):
    """The :class:`Noise` of ``points`` (as :func:`sample` takes them), read on their
    :func:`sample` (``taken``: the sample already taken)."""
    sample_, stride = sample(points) if taken is None else taken
    lengths = [k for k in PROBE["lengths"] if k < sample_.shape[0]] or [sample_.shape[0] - 1]
    graph = knn_graph(sample_, lengths[-1], False)
    scale, radius = core.local_noise(sample_, graph, np.array(lengths, np.int64))
    readings = {}
    for col, length in enumerate(lengths):
        read, mean_radius = float(np.median(scale[:, col])), surface_radius(radius[:, col])
        table = CALIBRATION[min(CALIBRATION, key=lambda k: abs(k - length))]
        readings[length] = {"read": read, "radius": mean_radius,
                            "sigma": invert(read, mean_radius, table)}
    usable = [r["sigma"] for r in readings.values()
              if r["radius"] >= PROBE["min_ratio"] * r["sigma"]]
    sigma = min(usable) if usable else readings[lengths[-1]]["sigma"]
    # On a surface a list of k points covers about pi r^2 = k s^2 (s the sample's spacing).
    spacing = readings[lengths[-1]]["radius"] * math.sqrt(math.pi / lengths[-1]) / math.sqrt(
        stride)
    return Noise(sigma, spacing, stride, readings)


def surface_radius(radius):
    """The mean of the list ``radius`` of the points on the surface: those within
    ``PROBE["stray"]`` times the median. One point far from the rest would otherwise set the
    spacing, and with it every list's bound, alone."""
    return surface_mean(radius, PROBE["stray"])


def own_sigma(points, taken, k, bound, radius):
    """The noise as the refinement's own fits read it on the probe's sample (every ``s``-th
    point of it, at most :data:`OWN_POINTS`): each such point's ``k`` nearest points of
    ``points`` within ``bound`` (:func:`sampled_variances`; what offers
    ``sampled_variances(sample, k, bound)`` reads them itself, out of core), the root mean of
    their :func:`own_variances`, read back through :data:`OWN_CALIBRATION` for lists of mean
    ``radius`` (:func:`invert`). ``taken``: :func:`sample`'s."""
    reader = getattr(points, "sampled_variances", None)
    every = -(-taken[0].shape[0] // OWN_POINTS)
    variances = (reader if reader is not None else partial(sampled_variances, points))(
        taken[0][::every], k, bound)
    finite = variances[np.isfinite(variances)]
    read = math.sqrt(float(np.mean(finite))) if finite.shape[0] else 0.0
    return invert(read, radius, OWN_CALIBRATION)


def sampled_variances(points, sample_, k, bound):
    """:func:`own_variances` of the lists of ``sample_``'s ``k`` nearest ``points`` within
    ``bound`` (``sample_`` among ``points``, so each list starts with its own point)."""
    n = points.shape[0]
    out = np.empty(sample_.shape[0])
    for start, stop, distances, rows in candidates(points, sample_, k + 1, bound, OWN_BLOCK):
        kept, lengths, _ = merge_candidates(distances, rows, k, n)
        out[start:stop] = own_variances(points[np.minimum(kept, n - 1)], lengths)
    return out


def own_variances(lists, lengths):
    """What each list's own fit reads of the noise: the squared height of the feature-aware
    quadratic (robust alternative included, no normal weights) of the first ``lengths[i]``
    points of ``lists[i]`` (``(m, k, 3)``, the point itself first), in the frame of their PCA
    normal, over ``1 - H``, ``H`` the plain fit's leverage on the point
    (:func:`pssd_fast.core.own_fits`); NaN for an empty list."""
    m, k = lengths.shape[0], lists.shape[1]
    has = lengths > 0
    flat = lists[np.arange(k) < lengths[:, None]]
    total = flat.shape[0]
    firsts = (np.cumsum(lengths) - lengths)[has]
    width = np.int32 if total < 2**31 else np.int64
    # The PCA kernel reads a list for every row: the others list themselves alone.
    per_row = np.ones(total, np.int64)
    per_row[firsts] = lengths[has]
    indptr = np.concatenate(([0], np.cumsum(per_row)))
    indices = np.arange(total, dtype=width).repeat(per_row)
    owner = np.repeat(firsts, lengths[has])
    indices[np.repeat(indptr[firsts], lengths[has]) + np.arange(total) - owner] = \
        np.arange(total)
    normals, _ = core.pca_normals(flat, NeighborGraph(indptr, indices, None), flat)
    lists_of = NeighborGraph(np.concatenate(([0], np.cumsum(lengths[has]))),
                             np.arange(total, dtype=width), None)
    height, _, _, leverage = core.own_fits(flat, normals, lists_of, 0.0, flat[firsts])
    out = np.full(m, np.nan)
    out[has] = height * height / np.maximum(1.0 - leverage, np.finfo(np.float64).eps)
    return out


def invert(read, radius, table):
    """The noise ``sigma`` whose reading, by lists of mean ``radius``, is ``read``: the root of
    ``sigma * f(radius / sigma) = read``, ``f`` the ``table`` (log-linear between its rows and
    held at its ends). 0 where nothing was read."""
    if not read > 0.0:
        return 0.0
    xs, fs = (np.log(np.array(column)) for column in zip(*table))

    def reads(log_sigma):
        x = math.log(radius) - log_sigma
        return log_sigma + float(np.interp(x, xs, fs))

    # ``reads`` grows with sigma (the tabulated f falls slower than 1 / x): bisect in log.
    low, high = math.log(read) - 1.0, math.log(read) + 10.0
    target = math.log(read)
    for _ in range(80):
        mid = 0.5 * (low + high)
        if reads(mid) < target:
            low = mid
        else:
            high = mid
    return math.exp(0.5 * (low + high))
