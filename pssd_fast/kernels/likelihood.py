"""Sampling likelihood from the MLS residuals (docs/ALGORITHM.md, step 1, eq. (2)
reconstructed)."""
import math

from numba import prange

from .config import CHUNK, parallel_kernel

# Codes of the ``likelihood`` forms, in the order of docs/ALGORITHM.md.
EXP, RATIO, RESIDUAL = 0, 1, 2


@parallel_kernel
def sampling_likelihood(resid, mean_resid, form, out):
    """Map residuals ``d_i`` to likelihoods ``l_i`` relative to their mean ``dbar``.

    Parameters
    ----------
    resid : (n,) float64
        MLS residuals ``d_i >= 0``.
    mean_resid : float
        ``dbar``, the mean residual over the whole model (computed by the caller).
    form : int
        ``EXP``: ``exp(-d_i / dbar)``; ``RATIO``: ``min(dbar / d_i, 1)``; ``RESIDUAL``:
        ``d_i / dbar``.
    out : (n,) float64
        Output likelihoods.

    Notes
    -----
    When ``dbar == 0`` every point lies on its fitted surface: ``EXP`` and ``RATIO`` give 1 and
    ``RESIDUAL`` gives 0, with no division by zero. ``RATIO`` gives 1 where ``d_i == 0``.
    """
    n = resid.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            d = resid[i]
            if form == RESIDUAL:
                out[i] = d / mean_resid if mean_resid > 0.0 else 0.0
            elif mean_resid <= 0.0:
                out[i] = 1.0
            elif form == EXP:
                out[i] = math.exp(-d / mean_resid)
            else:
                out[i] = min(mean_resid / d, 1.0) if d > 0.0 else 1.0
