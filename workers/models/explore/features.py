"""Per-pixel network inputs from G-buffers (App. A.5 [code]): position normalised to [0, 1] by the scene's
box, shading normal as n/2 + 1/2, w_o, albedo, roughness (13 channels), then v repeated per pixel. A pixel
whose ray escaped has all 13 zero (`network.escaped`).

One function builds them for training patches and for inference frames, so the channel order cannot
differ between the two (the authors' validation loader ordered buffers differently from the renderer).
"""

from __future__ import annotations

import numpy as np

from workers.render.gbuffer import GBuffers

BUFFER_CHANNELS = 13  # position 3, normal 3, w_o 3, albedo 3, roughness 1
POSITION = slice(0, 3)
NORMAL = slice(3, 6)  # n/2 + 1/2 of a unit n: never all zero, so all zero marks an escaped ray


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
