"""Tiled runs on Dask, with the in-core result (docs/tiled.md; docs/ALGORITHM.md, "Tiles").

:func:`denoise` tiles an array and :func:`denoise_file` a file on disk; both give what
:func:`pssd_fast.denoise` gives, bit for bit: the default method's steps run as rounds of tile
tasks of the one executor (:mod:`pssd_fast.executor`). :mod:`.runner` sets the runs up,
:mod:`.scheduler` runs the tasks on Dask, and :mod:`.ondisk` reads a cloud on disk in chunks
and bins it into tiles.

Dask is an optional dependency: ``pip install ".[dask]"`` in the repository.
"""
from .runner import FILE_KINDS, LOCAL_SCHEDULERS, denoise, denoise_file

__all__ = ["FILE_KINDS", "LOCAL_SCHEDULERS", "denoise", "denoise_file"]
