"""Tiled runs on Dask, with the in-core result (docs/tiled.md; docs/ALGORITHM.md, "Tiled runs").

:func:`denoise` tiles an array and :func:`denoise_file` a file on disk; both give what
:func:`pssd_fast.denoise` gives, bit for bit. :mod:`.runner` plans the run and schedules the
tiles, :mod:`.halo` widens the tiles of the routes that iterate on the points, and
:mod:`.ondisk` reads a cloud on disk in chunks and bins it into tile files.

Dask is an optional dependency: ``pip install "pssd_fast[dask]"``.
"""
from .runner import FILE_KINDS, LOCAL_SCHEDULERS, denoise, denoise_file

__all__ = ["FILE_KINDS", "LOCAL_SCHEDULERS", "denoise", "denoise_file"]
