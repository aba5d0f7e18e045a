"""Compiling the kernels: where numba's machine code is cached (:mod:`.cache`) and compiling
every kernel ahead of time (:mod:`.warmup`).

Importing this package makes the kernel cache the kernels' loader (see
:class:`pssd_fast.kernels.config.Kernel`); it creates no folder until the first kernel call.
"""
from ..kernels.config import Kernel
from . import cache

Kernel.loader = cache.prepare
