"""Per-iteration records shared by the pipelines that fit surfaces."""
import numpy as np

from .. import core


def fit_record(times, h, degree):
    """The ``stats`` record of an iteration with an MLS fit: times, ``h`` and degree counts."""
    counts = np.bincount(degree, minlength=4)
    return {"times": times, "h": h,
            "fit_degree": {name: int(counts[code]) for name, code in core.FIT_DEGREES.items()}}
