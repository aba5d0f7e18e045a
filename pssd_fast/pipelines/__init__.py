"""One module per pipeline of :func:`pssd_fast.denoise`, each with one entry, ``step``.

A step takes the current points (Morton order, float64), their normals for this iteration, the
neighbour graph, ``lam``, the method's parameters, a :class:`~pssd_fast.progress.Clock` that
times each stage, and whether this is the last iteration. It returns the moved points, the
normals to report, ``(likelihood, feature_intensity)`` or None, the iteration's record for
``stats`` and the mask of the points it held in place (their move was not finite, or longer
than the radius of the list behind it: docs/DECISIONS.md, "No point flung").
"""
from . import aware, bilateral, mls, paper

#: The step of each pipeline: the robust method's two pipelines and the two baselines.
STEPS = {"paper": paper.step, "bilateral": bilateral.step, "mls": mls.step}

__all__ = ["STEPS", "aware", "bilateral", "mls", "paper"]
