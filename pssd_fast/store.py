"""Where a tiled run keeps its tiles' arrays between its steps: here, or in files of a scratch
folder that every task reads and writes (docs/ALGORITHM.md, "Tiles").

Each entry is a tile's named arrays at one step (``key``: a tuple such as ``("cells", tile,
iteration)``); a task reads its own tile's entry whole and, from the other tiles' entries of
the same step, only the rows inside its halo (:meth:`Files.rows`: those rows alone).
"""
import pickle
import shutil
import threading
from pathlib import Path

import numpy as np

from . import atomic
from . import regions
from .graph import inside_boxes


#: numpy reads a ``.npy`` header with ``ast.literal_eval``, which CPython 3.11 before 3.11.8
#: can fail ("AST constructor recursion depth mismatch", gh-106905) in threads that run it at
#: once, as a threaded run's tasks do: one thread reads a header at a time.
_HEADERS = threading.Lock()


def load(path, mmap_mode=None):
    """``np.load(path, mmap_mode)`` of a ``.npy`` file (no pickles), safe in threads."""
    with _HEADERS:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)


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

    def rows(self, key, names, rows):
        """The arrays ``names`` of entry ``key``, at ``rows`` only."""
        entry = self.entries[key]
        return {name: entry[name][rows] for name in names}

    def drop(self, key):
        self.entries.pop(key, None)


class Files:
    """The entries as files of ``folder``, a folder an entry and a file a value (an array as
    ``.npy``, anything else pickled), each written whole: the runs from a file to a file, and
    tiled runs in other processes. A task that reads some rows of another tile's entry reads
    those rows alone (a memory map of each array it names)."""

    def __init__(self, folder):
        self.folder = Path(folder)

    def _path(self, key):
        return self.folder / "_".join(map(str, key))

    def put(self, key, arrays):
        # Each file whole through a temporary name: a task run again (a worker thought lost)
        # writes the same values, so a reader meets whole files of either run.
        folder = self._path(key)
        folder.mkdir(exist_ok=True)
        for path in folder.iterdir():  # values an earlier put of the entry had, and this lacks
            if not path.name.startswith(".") and path.stem not in arrays:
                path.unlink(missing_ok=True)
        for name, value in arrays.items():
            array = isinstance(value, np.ndarray)
            with atomic.scratch(folder / (name + (".npy" if array else ".pkl"))) as fh:
                if array:
                    np.save(fh, np.ascontiguousarray(value), allow_pickle=False)
                else:
                    pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)

    def get(self, key, names=None):
        folder = self._path(key)
        if names is None:
            names = sorted({path.stem for path in folder.iterdir()
                            if path.suffix in (".npy", ".pkl") and not path.name.startswith(".")})
        return {name: self._read(folder, name) for name in names}

    def rows(self, key, names, rows):
        """The arrays ``names`` of entry ``key``, at ``rows`` only (read through a memory map:
        the pages that hold them)."""
        folder = self._path(key)
        return {name: load(folder / f"{name}.npy", "r")[rows] for name in names}

    @staticmethod
    def _read(folder, name):
        path = folder / f"{name}.npy"
        if path.exists():
            return load(path)
        with open(folder / f"{name}.pkl", "rb") as fh:
            return pickle.load(fh)

    def drop(self, key):
        shutil.rmtree(self._path(key), ignore_errors=True)


def gather(store, keys, own, boxes, region, names, position, near=None):
    """A task's items: those of its own entry ``keys[own]``, then, of every other entry whose
    ``boxes`` (``(p, 2, 3)`` each) meet the boxes ``region`` (None: the task covers every
    tile), the rows whose ``position`` lies inside ``region`` (with ``near``, ``(centres,
    radius)``: within ``radius`` of one of ``centres`` instead); the arrays ``names``
    concatenated in that order (the own entry's arrays themselves where no other entry is
    read: tasks never change an array they read). Each entry's rows are in the order of the
    whole cloud (the tiles follow it), so the halo's rows are too."""
    return gather_halo(store, keys, own, boxes, region, names, position, near)[0]


def gather_halo(store, keys, own, boxes, region, names, position, near=None):
    """:func:`gather`, and the rows it took of each other entry (``[(i, rows)]``; rows None:
    all of them), which :func:`gather_again` takes of entries of the same rows."""
    parts = [store.get(keys[own], names)]
    picks = []
    for i, key in enumerate(keys):
        if i == own:
            continue
        if region is not None and not _meets(boxes[i], region):
            continue
        if region is None:
            rows, entry = None, store.get(key, names)
        else:
            at = store.get(key, (position,))[position]
            inside = inside_boxes(at, region) if near is None else regions.near(at, *near)
            rows = np.flatnonzero(inside)
            entry = store.rows(key, names, rows)
        parts.append(entry)
        picks.append((i, rows))
    return _joined(parts, names), picks


def gather_again(store, keys, own, picks, names):
    """:func:`gather` of entries ``keys`` whose rows are those of the entries an earlier
    :func:`gather_halo` read (the same points, other values): the rows it took, ``picks``,
    without testing positions again."""
    parts = [store.get(keys[own], names)]
    for i, rows in picks:
        parts.append(store.get(keys[i], names) if rows is None else
                     store.rows(keys[i], names, rows))
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
