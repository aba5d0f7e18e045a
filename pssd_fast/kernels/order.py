"""Spatial ordering: Morton codes and row permutations, in parallel (serial numpy fancy indexing
of (n, 3) rows was a tenth of a one-thread iteration at 1M points)."""
import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel


@helper
def _spread_bits(x):
    """Insert two zero bits between each of the low 21 bits of ``x`` (uint64)."""
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@parallel_kernel
def morton_codes(points, low, scale, out):
    """Interleaved 21-bit cell coordinates ``floor((p - low) * scale)`` of each point (x in
    bit 0, y in bit 1, z in bit 2 of each triple) into ``out`` (uint64)."""
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            code = np.uint64(0)
            for axis in range(3):
                cell = np.uint64((points[i, axis] - low[axis]) * scale)
                code |= _spread_bits(cell) << np.uint64(axis)
            out[i] = code


@parallel_kernel
def gather_rows(src, order, offset, out):
    """``out[i] = src[order[i]] - offset`` for every row ``i``."""
    n = order.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            for a in range(src.shape[1]):
                out[i, a] = src[order[i], a] - offset[a]


@parallel_kernel
def scatter_rows(src, order, offset, out):
    """``out[order[i]] = src[i] + offset`` for every row ``i`` (the inverse of
    :func:`gather_rows`)."""
    n = order.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            for a in range(src.shape[1]):
                out[order[i], a] = src[i, a] + offset[a]


@parallel_kernel
def cell_coordinates(points, low, scale, out):
    """The integer coordinates ``floor((p - low) * scale)`` of each point's grid cell into
    ``out`` ``(n, 3)`` int64 (every point at or above ``low``)."""
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            for axis in range(3):
                out[i, axis] = np.int64(np.uint64((points[i, axis] - low[axis]) * scale))


@parallel_kernel
def interleave(cells, shift, out):
    """The Morton code of each cell's coordinates shifted right by ``shift`` bits (at most 21
    bits an axis left) into ``out`` (uint64)."""
    n = cells.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            code = np.uint64(0)
            for axis in range(3):
                code |= _spread_bits(np.uint64(cells[i, axis]) >> np.uint64(shift)) << np.uint64(
                    axis)
            out[i] = code


#: Bits of the key sorted in each pass of :func:`stable_argsort`, and the blocks of rows each
#: pass counts and moves in parallel (fixed, not from the thread count: the order is the
#: stable one whatever the blocks, and they keep each block's counts small).
RADIX_BITS = 11
RADIX_BLOCKS = 64


@parallel_kernel
def stable_argsort(keys, out):
    """The permutation that sorts ``keys`` (uint64) stably, ties in their order, into ``out``
    (int64): ``np.argsort(keys, kind="stable")``.

    A least-significant-digit radix sort, :data:`RADIX_BITS` bits a pass, passes over digits
    that every key shares skipped (the high bits of codes from one part of a grid). Each pass
    counts the digits of :data:`RADIX_BLOCKS` blocks of rows, gives each block its own
    offsets after those of the earlier blocks, and moves the rows of each block in order:
    stable, so the passes sort by the whole key.
    """
    n = keys.shape[0]
    varying = np.uint64(0)
    if n:
        common = keys[0]
        for i in range(n):
            varying |= keys[i] ^ common
    size = (n + RADIX_BLOCKS - 1) // RADIX_BLOCKS
    digits = 1 << RADIX_BITS
    mask = np.uint64(digits - 1)
    order = np.arange(n)
    moved = np.empty(n, np.int64)
    key = keys.copy()
    moved_key = np.empty(n, np.uint64)
    counts = np.empty((RADIX_BLOCKS, digits), np.int64)
    for first_bit in range(0, 64, RADIX_BITS):
        shift = np.uint64(first_bit)
        if (varying >> shift) & mask == 0:
            continue
        for b in prange(RADIX_BLOCKS):
            counts[b, :] = 0
            for i in range(b * size, min(n, (b + 1) * size)):
                counts[b, (key[i] >> shift) & mask] += 1
        total = 0
        for d in range(digits):
            for b in range(RADIX_BLOCKS):
                count = counts[b, d]
                counts[b, d] = total
                total += count
        for b in prange(RADIX_BLOCKS):
            for i in range(b * size, min(n, (b + 1) * size)):
                d = (key[i] >> shift) & mask
                at = counts[b, d]
                counts[b, d] = at + 1
                moved[at] = order[i]
                moved_key[at] = key[i]
        order, moved = moved, order
        key, moved_key = moved_key, key
    out[:] = order
