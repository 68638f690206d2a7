"""Checkerboard shading of the indirect light: the network runs at half of a frame's pixels, those with
x + y even, and each other pixel takes the mean of its shaded 4-neighbours on the same surface (the same
object, normals within `SAME_SURFACE_COS`). A pixel with no such neighbour (a silhouette, a thin part) is
shaded as well. Indirect light varies slowly across a surface, so this halves the network's time, the
frame's largest cost on a CPU, for a small error (measured in `PrtConfig.checkerboard`)."""

from __future__ import annotations

import numpy as np

from workers.models.prt.gbuffer import SurfaceInputs

SAME_SURFACE_COS = 0.9  # neighbours whose normals differ by more than ~25 degrees are another surface
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))


def _shifted(array: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """array[y + dy, x + dx] at (y, x) over the image's first two axes, `fill` outside it."""
    out = np.full_like(array, fill)
    h, w = array.shape[:2]
    out[max(-dy, 0) : h - max(dy, 0), max(-dx, 0) : w - max(dx, 0)] = array[
        max(dy, 0) : h - max(-dy, 0), max(dx, 0) : w - max(-dx, 0)
    ]
    return out


def _checkerboard(height: int, width: int) -> np.ndarray:
    """(H, W) bool: the pixels with x + y even."""
    y, x = np.mgrid[0:height, 0:width]
    return (y + x) % 2 == 0


def _fill_weights(inputs: SurfaceInputs, modelled: np.ndarray, height: int, width: int) -> np.ndarray:
    """(4, H, W) bool: whether pixel (y, x) may take its 4-neighbour's value (the neighbour is shaded by
    the checkerboard, modelled, and on the same surface)."""
    on = modelled.reshape(height, width) & _checkerboard(height, width)
    object_id = inputs.object_id.reshape(height, width)
    normal = inputs.normal.reshape(height, width, 3)
    weights = []
    for dy, dx in _NEIGHBOURS:
        same_object = _shifted(object_id, dy, dx, -1) == object_id
        aligned = np.sum(_shifted(normal, dy, dx, 0.0) * normal, axis=-1) > SAME_SURFACE_COS
        weights.append(_shifted(on, dy, dx, False) & same_object & aligned)
    return np.stack(weights)


def shaded_pixels(inputs: SurfaceInputs, modelled: np.ndarray, height: int, width: int) -> np.ndarray:
    """(N,) bool: the modelled pixels the network evaluates, the checkerboard's and those with no
    neighbour to take a value from."""
    orphan = ~_fill_weights(inputs, modelled, height, width).any(axis=0)
    return modelled & (_checkerboard(height, width) | orphan).ravel()


def fill(
    values: np.ndarray,
    shaded: np.ndarray,
    modelled: np.ndarray,
    inputs: SurfaceInputs,
    height: int,
    width: int,
) -> np.ndarray:
    """`values` (N, 3), set at the `shaded` pixels, with every other modelled pixel the mean of its
    shaded same-surface 4-neighbours."""
    weights = _fill_weights(inputs, modelled, height, width).astype(values.dtype)
    image = values.reshape(height, width, -1)
    total = sum(
        w[..., None] * _shifted(image, dy, dx, 0) for w, (dy, dx) in zip(weights, _NEIGHBOURS, strict=True)
    )
    count = weights.sum(axis=0)[..., None]
    filled = (total / np.maximum(count, 1)).reshape(values.shape)
    out = values.copy()
    rest = modelled & ~shaded
    out[rest] = filled[rest]
    return out
