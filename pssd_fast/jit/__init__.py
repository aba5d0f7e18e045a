"""Where numba's machine code of the kernels is cached (:mod:`.cache`).

Importing this package makes the kernel cache the kernels' loader (see
:class:`pssd_fast.kernels.config.Kernel`); it creates no folder until the first kernel call.
"""
from ..kernels.config import Kernel
from . import cache

Kernel.loader = cache.prepare
