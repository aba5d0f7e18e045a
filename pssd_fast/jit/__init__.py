"""Where numba's machine code of the kernels is cached (:mod:`.cache`).

Importing this package makes the kernel cache the kernels' loader (see
:class:`pssd_fast.kernels.config.Kernel`); it creates no folder until the first kernel call.
:func:`clear_stale` removes the folders of other versions and CPUs, and nothing else does.
"""
from ..kernels.config import Kernel
from . import cache
from .cache import clear_stale

Kernel.loader = cache.prepare


def refuse_kernels(why):
    """Every kernel call from now on raises a RuntimeError saying ``why``."""
    Kernel.refused = why


__all__ = ["clear_stale", "refuse_kernels"]
