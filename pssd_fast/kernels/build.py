"""Child process of :class:`pssd_fast.kernels.cache.Kernel`: compile one kernel signature into
the cache and leave a marker file saying so.

Reads ``(module, name, argument types, marker path)`` pickled on standard input.
"""
import importlib
import pickle
import sys
from pathlib import Path


def main():
    module, name, types, marker = pickle.loads(sys.stdin.buffer.read())
    kernel = getattr(importlib.import_module(module), name)
    kernel.dispatcher.compile(types)
    marker = Path(marker)
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()


if __name__ == "__main__":
    main()
