"""Where a tiled run keeps its tiles' arrays between its steps: here, or in files of a scratch
folder that every task reads and writes (docs/ALGORITHM.md, "Tiles").

Each entry is a tile's named arrays at one step (``key``: a tuple such as ``("cells", tile,
iteration)``); a task reads its own tile's entry whole and, from the other tiles' entries of
the same step, only the rows inside its halo.
"""
import pickle
from pathlib import Path

import numpy as np

from . import atomic
from . import regions


class Memory:
    """The entries as arrays of this process: the in-core run and the tiled runs on Dask's
    threads."""

    def __init__(self):
        self.entries = {}

    def put(self, key, arrays):
        self.entries[key] = dict(arrays)

    def get(self, key, names=None):
        # A new dict: a task that updates what it read never changes the entry others read.
        entry = self.entries[key]
        return dict(entry) if names is None else {name: entry[name] for name in names}

    def drop(self, key):
        self.entries.pop(key, None)


class Files:
    """The entries as files of ``folder`` (one pickle of arrays an entry, written whole): the
    runs from a file to a file, and tiled runs in other processes."""

    def __init__(self, folder):
        self.folder = Path(folder)

    def _path(self, key):
        return self.folder / ("_".join(map(str, key)) + ".pkl")

    def put(self, key, arrays):
        with atomic.scratch(self._path(key)) as fh:
            pickle.dump({name: np.ascontiguousarray(a) if isinstance(a, np.ndarray) else a
                         for name, a in arrays.items()}, fh, protocol=pickle.HIGHEST_PROTOCOL)

    def get(self, key, names=None):
        with open(self._path(key), "rb") as fh:
            entry = pickle.load(fh)
        return entry if names is None else {name: entry[name] for name in names}

    def drop(self, key):
        self._path(key).unlink(missing_ok=True)


def gather(store, keys, own, boxes, region, names, position):
    """A task's items: those of its own entry ``keys[own]``, then, of every other entry whose
    ``boxes`` (``(p, 2, 3)`` each) meet the boxes ``region`` (None: the task covers every
    tile), the rows whose ``position`` lies inside ``region``; the arrays ``names``
    concatenated in that order (the own entry's arrays themselves where no other entry is
    read: tasks never change an array they read). Each entry's rows are in the order of the
    whole cloud (the tiles follow it), so the halo's rows are too."""
    return gather_halo(store, keys, own, boxes, region, names, position)[0]


def gather_halo(store, keys, own, boxes, region, names, position):
    """:func:`gather`, and the rows it took of each other entry (``[(i, rows)]``; rows None:
    all of them), which :func:`gather_again` takes of entries of the same rows."""
    parts = [store.get(keys[own], names)]
    picks = []
    for i, key in enumerate(keys):
        if i == own:
            continue
        if region is not None and not _meets(boxes[i], region):
            continue
        entry = store.get(key, names)
        rows = None
        if region is not None:
            rows = np.flatnonzero(regions.within(entry[position], region))
            entry = {name: value[rows] for name, value in entry.items()}
        parts.append(entry)
        picks.append((i, rows))
    return _joined(parts, names), picks


def gather_again(store, keys, own, picks, names):
    """:func:`gather` of entries ``keys`` whose rows are those of the entries an earlier
    :func:`gather_halo` read (the same points, other values): the rows it took, ``picks``,
    without testing positions again."""
    parts = [store.get(keys[own], names)]
    for i, rows in picks:
        entry = store.get(keys[i], names)
        parts.append(entry if rows is None else
                     {name: value[rows] for name, value in entry.items()})
    return _joined(parts, names)


def _joined(parts, names):
    """The parts' arrays ``names`` concatenated (the only part's own where one)."""
    if len(parts) == 1:
        return parts[0]
    return {name: np.concatenate([part[name] for part in parts]) for name in names}


def _meets(boxes, region):
    """Whether any of ``boxes`` meets any of ``region`` (both ``(p, 2, 3)``)."""
    low = np.maximum(boxes[:, None, 0], region[None, :, 0])
    high = np.minimum(boxes[:, None, 1], region[None, :, 1])
    return bool((low <= high).all(axis=2).any())
