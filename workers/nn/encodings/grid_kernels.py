"""Fused CPU kernels of the grid encodings: every level and corner of a batch in one compiled call.

The PyTorch path of `grid.py` runs a dozen tensor operations per level and recomputes rows and weights
in its backward; on a CPU that is dominated by dispatch and memory traffic. These kernels compute a
point's per-dimension key terms and weights once per level, form each corner's row and d-linear
weight from them in registers and gather or scatter at once, level after level. The dimension and
feature counts arrive as the lengths of tuples (`primes`, `features`), so Numba compiles them in as
constants; rows index the table as unsigned integers, which spares every access Numba's negative-index
wraparound.

- The forward runs in parallel over (level, chunk of points) tasks; each point writes only its own
  output entries.
- The backward runs in parallel over levels: a level's rows are its own block of the table, so no two
  threads add to the same row, and each level adds its points in order; the input gradient's per-level
  terms are summed in level order afterwards. The results are therefore the same bit for bit whatever
  the thread count.

The helpers are plain compiled functions, which LLVM inlines into the kernels; Numba's IR-level
`inline="always"` gave the same speed (hash grid forward + backward at 2^18 points, one thread) but took
4x the compile time (a backward specialisation: 42 CPU s against 10 on an empty cache), paid in every
fresh environment for every (dimension, feature count, dtype) in use.

Arithmetic is in the table's dtype (float32 in training, float64 in gradchecks), the same operations in
the same order as the PyTorch path: position = x * scale + 0.5, weights multiplied dimension 0 first.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numba
import numpy as np
from numba import prange
from numba.core import types
from numba.cpython.unsafe.tuple import tuple_setitem
from numba.extending import intrinsic, overload
from numba.np.unsafe.ndarray import to_fixed_tuple

from workers.render.jit import njit

# OpenMP or TBB: both may be entered from several Python threads at once (an inference server's pool);
# numba's fallback "workqueue" layer aborts the process when that happens.
numba.config.THREADING_LAYER = "threadsafe"

POINTS_PER_CHUNK = 1024


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


class GridArrays(NamedTuple):
    """Everything a kernel reads about the grid besides the points and the table, as one argument.

    Numba passes a named tuple as a struct of its members, so the compiled code is that of separate
    arguments; `primes` and `features` are tuples for their lengths (module docstring)."""

    starts: np.ndarray  # int64 [L]: the first row of each level's block of the table
    scales: np.ndarray  # [L], the table's dtype: lattice position = x * scale + 0.5
    sides: np.ndarray  # int64 [L]: lattice vertices per side
    primes: tuple[int, ...]  # d entries: the hash's per-dimension primes
    features: tuple[int, ...]  # F entries: only the length is read
    rules: np.ndarray  # the rest as in `KernelIndexing`
    sizes: np.ndarray
    lookup_starts: np.ndarray
    lookup: np.ndarray


_LINEAR = int(RowRule.LINEAR)
_HASHED = int(RowRule.HASHED)
_ROW_MAP = int(RowRule.ROW_MAP)


def _as_tuple(array, like):
    """The first len(like) entries of `array` as a tuple (compiled code only)."""
    raise NotImplementedError


@overload(_as_tuple, inline="always")
def _as_tuple_of_length(array, like):
    count = len(like)  # a compile-time constant: a tuple's length is part of its type
    return lambda array, like: to_fixed_tuple(array, count)


@intrinsic
def _repeat(typingctx, value, like):
    """A tuple of len(like) copies of `value`: its length is part of its type, as in `_as_tuple`."""
    repeated = types.UniTuple(value, len(like))

    def codegen(context, builder, signature, args):
        return context.make_tuple(builder, repeated, [args[0]] * len(like))

    return repeated(value, like), codegen


@njit(cache=True)
def _cell(point, scale, side, rule, primes, one):
    """The per-dimension terms of the cell holding `point` at a level of lattice scale `scale`, from
    which `_corner` forms each of the 2^d corners: (lower key terms, upper key terms, lower weights,
    upper weights), one entry per dimension.

    Along dimension i the cell spans c_i and c_i + 1 (c_i = floor of the position) and the point lies
    at fraction f_i; the key terms are c_i * m_i and (c_i + 1) * m_i, with m_i = prime_i on hashed
    levels and side^i on every other rule, and the weights 1 - f_i and f_i. Computing these once per
    point and level instead of once per corner spares 2^d - 1 floors, conversions and multiplications
    per dimension. The tuples stay in registers (the corner loop unrolls), unlike the per-point
    arrays that `_corner`'s predecessor measured 1.7x slower.
    """
    n_dims = len(primes)
    half = one / (one + one)  # 0.5 in the points' dtype (`one` is 1 in it)
    lower_keys = upper_keys = _repeat(np.int64(0), primes)
    lower_weights = upper_weights = _repeat(one - point[0], primes)  # typed as one - f_i
    factor = np.int64(1)
    for i in range(n_dims):
        position = point[i] * scale + half
        floor = np.floor(position)
        fraction = position - floor
        multiplier = primes[i] if rule == _HASHED else factor
        lower_keys = tuple_setitem(lower_keys, i, np.int64(floor) * multiplier)
        upper_keys = tuple_setitem(upper_keys, i, (np.int64(floor) + 1) * multiplier)
        lower_weights = tuple_setitem(lower_weights, i, one - fraction)
        upper_weights = tuple_setitem(upper_weights, i, fraction)
        factor *= side
    return lower_keys, upper_keys, lower_weights, upper_weights


@njit(cache=True)
def _corner(cell, corner, rule, one):
    """Key and d-linear weight of corner number `corner` of a `_cell`.

    Bit d-1-i of the corner number is its offset along dimension i (`outer_combine` order). The key
    combines the terms by XOR (hashed levels) or by sum (every other rule: the vertex's linear index,
    dimension 0 fastest). The weight multiplies the per-dimension weights dimension 0 first, as the
    PyTorch path does, so the two agree bit for bit.
    """
    lower_keys, upper_keys, lower_weights, upper_weights = cell
    n_dims = len(lower_keys)
    key = np.int64(0)
    weight = one
    for i in range(n_dims):
        upper = (corner >> (n_dims - 1 - i)) & 1
        term = upper_keys[i] if upper else lower_keys[i]
        key = key ^ term if rule == _HASHED else key + term
        weight = weight * (upper_weights[i] if upper else lower_weights[i])
    return key, weight


@njit(cache=True)
def _corner_slope(cell, corner, dim, one):
    """d weight / d f_dim of `corner`: the other dimensions' weights times -1 (lower) or +1 (upper)."""
    _, _, lower_weights, upper_weights = cell
    n_dims = len(lower_weights)
    slope = one
    for i in range(n_dims):
        upper = (corner >> (n_dims - 1 - i)) & 1
        if i == dim:
            slope = slope * (one if upper else -one)
        else:
            slope = slope * (upper_weights[i] if upper else lower_weights[i])
    return slope


@njit(cache=True)
def _row(key, rule, size, lookup_start, lookup):
    """Row within the level's block (of `size` rows) of the vertex with `key`, or -1 when it is not
    stored. `lookup[lookup_start:]` is the level's lookup table (SORTED_KEYS and ROW_MAP levels)."""
    if rule == _HASHED:
        return key & (size - 1)
    if rule == _LINEAR:
        return key
    if rule == _ROW_MAP:
        return lookup[lookup_start + key]
    low, high = lookup_start, lookup_start + size
    while low < high:
        middle = (low + high) // 2
        if lookup[middle] < key:
            low = middle + 1
        else:
            high = middle
    if low < lookup_start + size and lookup[low] == key:
        return low - lookup_start
    return -1


@njit(cache=True)
def _stored(rule, row):
    """Whether a row from `_row` is stored: always on LINEAR and HASHED levels (no test compiled in)."""
    if rule == _HASHED:
        return True
    return rule == _LINEAR or row >= 0


@njit(cache=True)
def _level_in_slot(slot, n_levels):
    """The level a parallel loop works on in its `slot`-th turn: even levels first, then odd ones.

    Numba's parallel loops hand each thread a contiguous range of turns. In level order two threads
    would get the coarse levels (dense, cache-resident, cheap) and the fine hashed ones (4 MB blocks,
    slow); interleaved, each gets a mix and they finish together.
    """
    half = (n_levels + 1) // 2
    return 2 * slot if slot < half else 2 * (slot - half) + 1


@njit(cache=True)
def _forward_points(x, table, first, last, level, rule, grid, out):
    """`grid_forward` for points first .. last - 1 at one level."""
    one = table.dtype.type(1.0)
    start, scale, side = grid.starts[level], grid.scales[level], grid.sides[level]
    size, lookup_start = grid.sizes[level], grid.lookup_starts[level]
    n_features = len(grid.features)
    for n in range(first, last):
        # A row view: here (no stores between corners) it measured faster than a tuple copy.
        cell = _cell(x[n], scale, side, rule, grid.primes, one)
        for f in range(n_features):
            total = table.dtype.type(0.0)
            for corner in range(1 << len(grid.primes)):
                key, weight = _corner(cell, corner, rule, one)
                row = _row(key, rule, size, lookup_start, grid.lookup)
                if _stored(rule, row):
                    total += weight * table[np.uint64(start + row), f]
            out[n, np.uint64(level * n_features + f)] = total


@njit(parallel=True, cache=True)
def grid_forward(x, table, grid, out):
    """out[n, l * F + f] = sum over corners c of w_c(x_n) * table[start_l + row_c, f].

    Tasks are (level, chunk of points), level-major, so a thread works through one level's block of the
    table at a time (a 2^19-row level is 4 MB: it stays in cache, all 16 levels would not); each task
    writes only its own columns of its own rows of `out`.
    """
    n_points, n_levels = x.shape[0], grid.starts.shape[0]
    n_chunks = (n_points + POINTS_PER_CHUNK - 1) // POINTS_PER_CHUNK
    # A parallel loop cannot capture a named tuple of arrays (Numba's gufunc wrapper reads its tuple
    # members as arrays and fails to compile): the loop captures the members, and each task packs them
    # again, which compiles away.
    starts, scales, sides, primes, features, rules, sizes, lookup_starts, lookup = grid
    for task in prange(n_levels * n_chunks):
        task_grid = GridArrays(starts, scales, sides, primes, features, rules, sizes, lookup_starts, lookup)
        level, chunk = _level_in_slot(task // n_chunks, n_levels), task % n_chunks
        first, last = chunk * POINTS_PER_CHUNK, min(n_points, (chunk + 1) * POINTS_PER_CHUNK)
        # The same call with the rule as a constant where it is arithmetic, so the lookups and the
        # stored-row test drop out of the compiled loop.
        rule = rules[level]
        if rule == _HASHED:
            _forward_points(x, table, first, last, level, _HASHED, task_grid, out)
        elif rule == _LINEAR:
            _forward_points(x, table, first, last, level, _LINEAR, task_grid, out)
        else:
            _forward_points(x, table, first, last, level, rule, task_grid, out)


@njit(cache=True)
def _table_gradient_points(x, grad_out, level, rule, grid, grad_table):
    """The table gradient of one level: every point in order adds to the level's block of `grad_table`."""
    one = grad_table.dtype.type(1.0)
    start, scale, side = grid.starts[level], grid.scales[level], grid.sides[level]
    size, lookup_start = grid.sizes[level], grid.lookup_starts[level]
    n_features = len(grid.features)
    for n in range(x.shape[0]):
        # A tuple copy: the scatter's stores may alias `x` as far as the compiler knows, so a row view
        # would be reread and the corner work redone after each one (measured 1.5x slower).
        cell = _cell(_as_tuple(x[n], grid.primes), scale, side, rule, grid.primes, one)
        for corner in range(1 << len(grid.primes)):
            key, weight = _corner(cell, corner, rule, one)
            row = _row(key, rule, size, lookup_start, grid.lookup)
            if _stored(rule, row):
                for f in range(n_features):
                    grad_table[np.uint64(start + row), f] += (
                        weight * grad_out[n, np.uint64(level * n_features + f)]
                    )


@njit(cache=True)
def _input_gradient_points(x, table, grad_out, level, rule, grid, terms):
    """The input gradient's terms of one level: terms[level, n, j] = scale_l * sum over corners c of
    (d w_c / d f_j) <table[row_c], grad_out[n, l]>."""
    one = table.dtype.type(1.0)
    start, scale, side = grid.starts[level], grid.scales[level], grid.sides[level]
    size, lookup_start = grid.sizes[level], grid.lookup_starts[level]
    n_features, n_dims = len(grid.features), len(grid.primes)
    for n in range(x.shape[0]):
        cell = _cell(_as_tuple(x[n], grid.primes), scale, side, rule, grid.primes, one)
        terms[level, n, :] = 0
        for corner in range(1 << n_dims):
            key, _ = _corner(cell, corner, rule, one)
            row = _row(key, rule, size, lookup_start, grid.lookup)
            if _stored(rule, row):
                dot = table.dtype.type(0.0)
                for f in range(n_features):
                    dot += table[np.uint64(start + row), f] * grad_out[n, np.uint64(level * n_features + f)]
                for dim in range(n_dims):
                    terms[level, n, dim] += _corner_slope(cell, corner, dim, one) * dot
        for dim in range(n_dims):
            terms[level, n, dim] *= scale


@njit(cache=True)
def _backward_level(x, table, grad_out, level, rule, grid, grad_table, terms):
    """The table gradient and the input gradient's terms of one level, each when its array is not empty."""
    if grad_table.shape[0] > 0:
        _table_gradient_points(x, grad_out, level, rule, grid, grad_table)
    if terms.shape[1] > 0:
        _input_gradient_points(x, table, grad_out, level, rule, grid, terms)


@njit(parallel=True, cache=True)
def grid_backward(x, table, grad_out, grid, grad_table, grad_x):
    """grad_table[start_l + row_c] = sum over points n of w_c(x_n) * grad_out[n, l], and
    grad_x[n, j] = sum_l scale_l * sum_c (d w_c / d f_j) <table[row_c], grad_out[n, l]>. An empty
    `grad_table` or `grad_x` (no rows) means that gradient is not wanted.

    `grad_table` need not be zeroed: each level zeroes its own block first, so the blocks must tile the
    table. Tasks are whole levels: a level's rows are its own block of the table, so no two threads add
    to the same row, and each level adds its points in order. The input gradient's per-level terms are
    summed in level order afterwards. Both results are therefore the same bit for bit whatever the
    thread count.
    """
    n_points, n_dims, n_levels = x.shape[0], len(grid.primes), grid.starts.shape[0]
    terms = np.empty((n_levels, n_points if grad_x.shape[0] > 0 else 0, n_dims), table.dtype)
    # As in `grid_forward`: the loop captures the grid's members and packs them again.
    starts, scales, sides, primes, features, rules, sizes, lookup_starts, lookup = grid
    for slot in prange(n_levels):
        task_grid = GridArrays(starts, scales, sides, primes, features, rules, sizes, lookup_starts, lookup)
        level = _level_in_slot(slot, n_levels)
        if grad_table.shape[0] > 0:
            grad_table[starts[level] : starts[level] + sizes[level]] = 0
        # As in `grid_forward`: the rule is a constant where it is arithmetic.
        rule = rules[level]
        if rule == _HASHED:
            _backward_level(x, table, grad_out, level, _HASHED, task_grid, grad_table, terms)
        elif rule == _LINEAR:
            _backward_level(x, table, grad_out, level, _LINEAR, task_grid, grad_table, terms)
        else:
            _backward_level(x, table, grad_out, level, rule, task_grid, grad_table, terms)
    n_chunks = (terms.shape[1] + POINTS_PER_CHUNK - 1) // POINTS_PER_CHUNK
    for chunk in prange(n_chunks):
        for n in range(chunk * POINTS_PER_CHUNK, min(n_points, (chunk + 1) * POINTS_PER_CHUNK)):
            for dim in range(n_dims):
                total = table.dtype.type(0.0)
                for level in range(n_levels):
                    total += terms[level, n, dim]
                grad_x[n, dim] = total
