"""Fused CPU kernels of the grid encodings: every level and corner of a batch in one compiled call.

The PyTorch path of `grid.py` runs a dozen tensor operations per level and recomputes rows and weights
in its backward; on a CPU that is dominated by dispatch and memory traffic. These kernels compute a
point's cell, corner rows, d-linear weights and the weighted sum in registers, level after level.

- Forward and the input gradient run in parallel over chunks of points (each point writes only its own
  output row).
- The table gradient runs in parallel over levels: a level's rows are its own block of the table, so no
  two threads add to the same row, and each level adds its points in order. The result is therefore
  the same bit for bit whatever the thread count.

Arithmetic is in the table's dtype (float32 in training, float64 in gradchecks), the same operations in
the same order as the PyTorch path: position = x * scale + 0.5, weights multiplied dimension 0 first.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numba
import numpy as np
from numba import prange

from workers.render.jit import njit

# OpenMP or TBB: both may be entered from several Python threads at once (an inference server's pool);
# numba's fallback "workqueue" layer aborts the process when that happens.
numba.config.THREADING_LAYER = "threadsafe"

POINTS_PER_CHUNK = 1024
POINTS_PER_BATCH = 32  # points whose corner rows are computed before the table is read


class RowRule(IntEnum):
    """How a level turns a corner vertex into a row of its block of the table."""

    LINEAR = 0  # dense level: the vertex's linear index, dimension 0 fastest
    HASHED = 1  # instant-ngp spatial hash: XOR of coordinate * prime, masked to the block size
    SORTED_KEYS = 2  # the position of the linear index in a sorted key list; absent keys are not stored
    ROW_MAP = 3  # a lookup table from linear index to row; -1 marks a vertex that is not stored


@dataclass(frozen=True)
class KernelIndexing:
    """Per-level row rules as flat arrays the kernels can read.

    `lookup[lookup_starts[l]:]` holds level l's sorted keys (SORTED_KEYS, `sizes[l]` of them) or its row
    map (ROW_MAP, one entry per lattice vertex); LINEAR and HASHED levels need none.
    """

    rules: np.ndarray  # int64 [L]
    sizes: np.ndarray  # int64 [L]: rows of the level's block
    lookup_starts: np.ndarray  # int64 [L]
    lookup: np.ndarray  # int64 [K]
    primes: np.ndarray  # int64 [d]: the hash's per-dimension primes (HASHED levels)

    @staticmethod
    def build(
        rules: list[RowRule],
        sizes: list[int],
        lookups: list[np.ndarray | None],
        primes: tuple[int, ...] = (0, 0, 0, 0),
    ) -> KernelIndexing:
        starts, offset = [], 0
        for table in lookups:
            starts.append(offset)
            offset += 0 if table is None else len(table)
        flat = [np.asarray(t, dtype=np.int64) for t in lookups if t is not None]
        return KernelIndexing(
            rules=np.asarray([int(rule) for rule in rules], dtype=np.int64),
            sizes=np.asarray(sizes, dtype=np.int64),
            lookup_starts=np.asarray(starts, dtype=np.int64),
            lookup=np.concatenate(flat) if flat else np.zeros(1, dtype=np.int64),
            primes=np.asarray(primes, dtype=np.int64),
        )


@njit(cache=True, inline="always")
def _level_pairs(x, n, scale, side, rule, primes, lower, upper, w_lower, w_upper):
    """Per dimension i, the key terms of the cell's lower and upper vertex along i and their linear
    weights 1 - f_i and f_i, for point n at a level of lattice scale `scale`.

    A corner's key combines one term per dimension: XOR of c_i * prime_i (hashed levels) or the sum of
    c_i * side^i (every other rule: the vertex's linear index, dimension 0 fastest).
    """
    one = w_lower.dtype.type(1.0)
    half = x.dtype.type(0.5)
    stride = np.int64(1)
    for i in range(x.shape[1]):
        position = x[n, i] * scale + half
        floor = np.floor(position)
        cell = np.int64(floor)
        fraction = position - floor
        w_lower[i] = one - fraction
        w_upper[i] = fraction
        factor = primes[i] if rule == 1 else stride
        lower[i] = cell * factor
        upper[i] = (cell + 1) * factor
        stride *= side


@njit(cache=True, inline="always")
def _corners(rule, lower, upper, w_lower, w_upper, keys, weights):
    """Keys and weights of all 2^d corners, built one dimension at a time as `outer_combine` does:
    corner 2j + b extends corner j of the dimensions so far by the lower (b = 0) or upper (b = 1) vertex,
    so bit d-1-i of a corner's number is its offset along dimension i, and a weight is the product of
    the per-dimension weights taken dimension 0 first."""
    keys[0] = 0
    weights[0] = w_lower.dtype.type(1.0)
    count = 1
    for i in range(lower.shape[0]):
        for j in range(count - 1, -1, -1):
            key, weight = keys[j], weights[j]
            if rule == 1:
                keys[2 * j], keys[2 * j + 1] = key ^ lower[i], key ^ upper[i]
            else:
                keys[2 * j], keys[2 * j + 1] = key + lower[i], key + upper[i]
            weights[2 * j], weights[2 * j + 1] = weight * w_lower[i], weight * w_upper[i]
        count *= 2


@njit(cache=True, inline="always")
def _corner_slope(corner, dim, w_lower, w_upper):
    """d weight / d f_dim of `corner`: the other dimensions' weights times -1 (lower) or +1 (upper)."""
    n_dims = w_lower.shape[0]
    one = w_lower.dtype.type(1.0)
    slope = one
    for i in range(n_dims):
        upper = (corner >> (n_dims - 1 - i)) & 1
        if i == dim:
            slope = slope * (one if upper else -one)
        else:
            slope = slope * (w_upper[i] if upper else w_lower[i])
    return slope


@njit(cache=True, inline="always")
def _row(key, level, rule, sizes, lookup_starts, lookup):
    """Row within the level's block of the vertex with `key`, or -1 when it is not stored."""
    if rule == 0:
        return key
    if rule == 1:
        return key & (sizes[level] - 1)
    start = lookup_starts[level]
    if rule == 3:
        return lookup[start + key]
    low, high = start, start + sizes[level]
    while low < high:
        middle = (low + high) // 2
        if lookup[middle] < key:
            low = middle + 1
        else:
            high = middle
    if low < start + sizes[level] and lookup[low] == key:
        return low - start
    return -1


@njit(cache=True, inline="always")
def _batch_corners(
    x, first, count, level, scales, sides, primes, rules, sizes, lookup_starts, lookup, scratch
):
    """Rows and weights of the corners of points first .. first + count - 1 at `level`, into
    `scratch.rows` and `scratch.weights` [POINTS_PER_BATCH, 2^d] (rows -1 where a vertex is not stored).

    Computing a batch's rows before touching the table turns the gathers and scatters that follow into
    a tight loop of independent loads, which the CPU overlaps: at 2^19-row levels (4 MB each, beyond L2)
    those random accesses, not the hashing, are most of the time.
    """
    lower, upper, w_lower, w_upper, keys, weights, rows, batch_weights = scratch
    rule = rules[level]
    for b in range(count):
        _level_pairs(x, first + b, scales[level], sides[level], rule, primes, lower, upper, w_lower, w_upper)
        _corners(rule, lower, upper, w_lower, w_upper, keys, weights)
        for corner in range(keys.shape[0]):
            rows[b, corner] = _row(keys[corner], level, rule, sizes, lookup_starts, lookup)
            batch_weights[b, corner] = weights[corner]


@njit(cache=True, inline="always")
def _scratch(n_dims, dtype):
    """Per-task work arrays of `_batch_corners`."""
    return (
        np.empty(n_dims, np.int64),
        np.empty(n_dims, np.int64),
        np.empty(n_dims, dtype),
        np.empty(n_dims, dtype),
        np.empty(1 << n_dims, np.int64),
        np.empty(1 << n_dims, dtype),
        np.empty((POINTS_PER_BATCH, 1 << n_dims), np.int64),
        np.empty((POINTS_PER_BATCH, 1 << n_dims), dtype),
    )


@njit(cache=True, inline="always")
def _level_in_slot(slot, n_levels):
    """The level a parallel loop works on in its `slot`-th turn: even levels first, then odd ones.

    Numba's parallel loops hand each thread a contiguous range of turns. In level order two threads
    would get the coarse levels (dense, cache-resident, cheap) and the fine hashed ones (4 MB blocks,
    slow); interleaved, each gets a mix and they finish together.
    """
    half = (n_levels + 1) // 2
    return 2 * slot if slot < half else 2 * (slot - half) + 1


@njit(parallel=True, cache=True)
def grid_forward(x, table, starts, scales, sides, primes, rules, sizes, lookup_starts, lookup, out):
    """out[n, l * F + f] = sum over corners c of w_c(x_n) * table[start_l + row_c, f].

    Tasks are (level, chunk of points), level-major, so a thread works through one level's block of the
    table at a time (a 2^19-row level is 4 MB: it stays in cache, all 16 levels would not); each task
    writes only its own columns of its own rows of `out`.
    """
    n_points, n_dims = x.shape
    n_levels, n_features = starts.shape[0], table.shape[1]
    n_chunks = (n_points + POINTS_PER_CHUNK - 1) // POINTS_PER_CHUNK
    for task in prange(n_levels * n_chunks):
        level, chunk = _level_in_slot(task // n_chunks, n_levels), task % n_chunks
        start = starts[level]
        scratch = _scratch(n_dims, table.dtype)
        rows, weights = scratch[6], scratch[7]
        chunk_end = min(n_points, (chunk + 1) * POINTS_PER_CHUNK)
        for first in range(chunk * POINTS_PER_CHUNK, chunk_end, POINTS_PER_BATCH):
            count = min(POINTS_PER_BATCH, chunk_end - first)
            _batch_corners(
                x, first, count, level, scales, sides, primes, rules, sizes, lookup_starts, lookup, scratch
            )
            for b in range(count):
                for f in range(n_features):
                    total = table.dtype.type(0.0)
                    for corner in range(1 << n_dims):
                        if rows[b, corner] >= 0:
                            total += weights[b, corner] * table[start + rows[b, corner], f]
                    out[first + b, level * n_features + f] = total


@njit(parallel=True, cache=True)
def grid_backward_table(
    x, grad_out, starts, scales, sides, primes, rules, sizes, lookup_starts, lookup, grad_table
):
    """grad_table[start_l + row_c] += w_c(x_n) * grad_out[n, l], one level per thread, points in order.

    Point by point, not in batches as the forward: batching the rows first measured slower here (each
    addition reads and writes its row, so the CPU cannot run ahead the way it does over gathers).
    """
    n_points, n_dims = x.shape
    n_features = grad_table.shape[1]
    for slot in prange(starts.shape[0]):
        level = _level_in_slot(slot, starts.shape[0])
        lower, upper = np.empty(n_dims, np.int64), np.empty(n_dims, np.int64)
        w_lower, w_upper = np.empty(n_dims, grad_table.dtype), np.empty(n_dims, grad_table.dtype)
        keys = np.empty(1 << n_dims, np.int64)
        weights = np.empty(1 << n_dims, grad_table.dtype)
        rule, start = rules[level], starts[level]
        for n in range(n_points):
            _level_pairs(x, n, scales[level], sides[level], rule, primes, lower, upper, w_lower, w_upper)
            _corners(rule, lower, upper, w_lower, w_upper, keys, weights)
            for corner in range(1 << n_dims):
                row = _row(keys[corner], level, rule, sizes, lookup_starts, lookup)
                if row >= 0:
                    for f in range(n_features):
                        grad_table[start + row, f] += weights[corner] * grad_out[n, level * n_features + f]


@njit(parallel=True, cache=True)
def grid_backward_input(
    x, table, grad_out, starts, scales, sides, primes, rules, sizes, lookup_starts, lookup, grad_x
):
    """grad_x[n, j] = sum_l scale_l * sum_c (d w_c / d f_j) <table[row_c], grad_out[n, l]>.

    Level-major like `grid_forward` (one level's block of the table in cache at a time): each
    (level, chunk) task writes its levels' terms to `terms` [L, N, d], then a pass over points adds
    them to grad_x in level order, so the sums do not depend on the thread count.
    """
    n_points, n_dims = x.shape
    n_levels, n_features = starts.shape[0], table.shape[1]
    n_chunks = (n_points + POINTS_PER_CHUNK - 1) // POINTS_PER_CHUNK
    terms = np.empty((n_levels, n_points, n_dims), table.dtype)
    for task in prange(n_levels * n_chunks):
        level, chunk = _level_in_slot(task // n_chunks, n_levels), task % n_chunks
        rule, start = rules[level], starts[level]
        lower, upper = np.empty(n_dims, np.int64), np.empty(n_dims, np.int64)
        w_lower, w_upper = np.empty(n_dims, table.dtype), np.empty(n_dims, table.dtype)
        keys = np.empty(1 << n_dims, np.int64)
        weights = np.empty(1 << n_dims, table.dtype)
        along = np.empty(n_dims, table.dtype)
        for n in range(chunk * POINTS_PER_CHUNK, min(n_points, (chunk + 1) * POINTS_PER_CHUNK)):
            _level_pairs(x, n, scales[level], sides[level], rule, primes, lower, upper, w_lower, w_upper)
            _corners(rule, lower, upper, w_lower, w_upper, keys, weights)
            along[:] = 0
            for corner in range(1 << n_dims):
                row = _row(keys[corner], level, rule, sizes, lookup_starts, lookup)
                if row < 0:
                    continue
                dot = table.dtype.type(0.0)
                for f in range(n_features):
                    dot += table[start + row, f] * grad_out[n, level * n_features + f]
                for dim in range(n_dims):
                    along[dim] += _corner_slope(corner, dim, w_lower, w_upper) * dot
            for dim in range(n_dims):
                terms[level, n, dim] = along[dim] * scales[level]
    for chunk in prange(n_chunks):
        for n in range(chunk * POINTS_PER_CHUNK, min(n_points, (chunk + 1) * POINTS_PER_CHUNK)):
            for level in range(n_levels):
                for dim in range(n_dims):
                    grad_x[n, dim] += terms[level, n, dim]
