"""The default method's steps run in order over a cloud (docs/ALGORITHM.md, "The default
method"): the cells, the iterations on their means, every point onto their fits, the test and
the failing points' own fits."""
import numpy as np

from . import core, method
from .pipelines import aware
from .progress import Clock
from .run import Iterated


def run(current, given, plan, request):
    """The default method on the distinct positions ``current`` (Morton order, relative to
    ``request.centre``), with the caller's normals ``given`` in that order or None: an
    :class:`~pssd_fast.run.Iterated` whose records are the iterations on the means (the last
    one's times with the points' steps added)."""
    params = request.params
    sigma_n, keep = params["sigma_n"], params["keep_normals"]
    cells = method.cells_of(current, given, plan.edge, plan.low)
    done = method.iterate(cells, plan.k, plan.bound, plan.iterations, sigma_n, cells.normals,
                          keep, request.report)
    clock = Clock(request.report, plan.iterations - 1, plan.iterations)
    moved, normals, held, nearest = clock.run("project", method.project, current, done,
                                              plan.bound)
    record = done.records[-1]
    record["cells"] = int(cells.counts.shape[0])
    if plan.refine is not None:
        step = moved - current
        fails = clock.run("test", method.failing, cells, np.einsum("ij,ij->i", step, step),
                          plan.noise.sigma, plan.bound)
        flagged = np.repeat(fails, cells.counts)[np.argsort(cells.order, kind="stable")]
        record["refined"] = int(flagged.sum())
        if flagged.any():
            start = moved.copy()
            start[flagged] = current[flagged]
            k, bound = plan.refine
            placed, refined, held_refined = method.refine(
                start, normals, flagged, k, bound, sigma_n, given, keep, clock)
            moved[flagged] = placed
            normals[flagged] = refined
            held[flagged] |= held_refined
    extra = None
    if request.extras:
        lik, feat = clock.run("extras", _extras, done)
        extra = (lik[nearest], feat[nearest])
    record["times"].update(clock.times)
    return Iterated(moved, normals, extra, done.records, held)


def _extras(done):
    """The likelihood and feature intensity of the means, which every point takes from its
    nearest: the likelihood from the last fits' RMS residual (the ``"exp"`` form), the feature
    intensity by the paper's voting at the paper's constants over the means."""
    lik, _ = core.sampling_likelihood(done.rms, "exp")
    feat = aware.voted_feature(done.origins, done.normals, done.lists,
                               aware.region_radius(core.mean_spacing(done.lists)))
    return lik, feat
