"""Per-pixel network inputs from G-buffers (App. A.5 [code]): position normalised to [0, 1] by the scene's
box, shading normal as n/2 + 1/2, w_o, albedo, roughness (13 channels), then v repeated per pixel.

One function builds them for training patches and for inference frames, so the channel order cannot
differ between the two (the authors' validation loader ordered buffers differently from the renderer).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from workers.render.gbuffer import GBuffers

BUFFER_CHANNELS = 13  # position 3, normal 3, w_o 3, albedo 3, roughness 1
POSITION = slice(0, 3)
NORMAL = slice(3, 6)
# A neighbour shows another surface when its normalised position is this far (a twentieth of the scene's
# box; a pixel of a 64^2 view spans about a sixtieth of it head-on) or its normal turns by ~25 degrees
EDGE_POSITION, EDGE_NORMAL_COS = 0.05, 0.9


def pixel_features(buffers: GBuffers, box: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(H, W, 13 + K) float32: the buffers in the documented order, then v, zero where nothing was hit."""
    lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
    hit = buffers.hit[..., None]
    position = np.where(hit, (buffers.position - lo) / np.maximum(hi - lo, 1e-12), 0.0)
    normal = np.where(hit, buffers.normal * 0.5 + 0.5, 0.0)
    h, w = buffers.hit.shape
    tiled = np.broadcast_to(np.asarray(v, np.float32), (h, w, len(v)))
    parts = [position, normal, buffers.wo, buffers.albedo, buffers.roughness, tiled]
    return np.concatenate([p.astype(np.float32) for p in parts], axis=-1)


def interior_pixels(features: Tensor, emission: Tensor) -> Tensor:
    """[..., H, W, 1] 1.0 where a pixel's 4-neighbours in the patch show the same surface as its centre
    (position, normal and whether it emits agree), else 0: at a surface's edge an area-sampled target
    mixes surfaces the centre's G-buffers do not show, an error no network fits."""
    position, normal = features[..., POSITION], features[..., NORMAL] * 2 - 1
    emits = (emission > 0).any(dim=-1, keepdim=True)
    interior = torch.ones_like(features[..., :1])
    for dim in (-3, -2):  # neighbours along rows, then columns
        (p0, p1), (n0, n1), (e0, e1) = (_neighbours(t, dim) for t in (position, normal, emits))
        same = (
            ((p0 - p1).abs().amax(dim=-1, keepdim=True) < EDGE_POSITION)
            & ((n0 * n1).sum(dim=-1, keepdim=True) > EDGE_NORMAL_COS)
            & (e0 == e1)
        ).to(features.dtype)
        pad = torch.ones_like(interior.narrow(dim, 0, 1))
        interior = interior * torch.cat([same, pad], dim) * torch.cat([pad, same], dim)
    return interior


def _neighbours(t: Tensor, dim: int) -> tuple[Tensor, Tensor]:
    """Each pixel but the last along `dim`, and the next one."""
    n = t.shape[dim]
    return t.narrow(dim, 0, n - 1), t.narrow(dim, 1, n - 1)
