"""Nearest training rows: for a surface point, the k rows of the same object nearest in position (in box
diagonals) and, weighted by `DIRECTION_WEIGHT`, reflected direction w_r (the inputs Eq. 4 gives position
and view dependence through).

A row traced at 128 paths is a noisy estimate of the pixel's transport (two independent traces of the same
pixels are 20.3 dB apart under a held-out lighting on env_lit_objects), and its per-wavelet Haar
coefficients, which `transport_weight` supervises, are noisier still. The mean of a row's nearest rows
trades that noise for a blur of the transport over the neighbourhood; training takes it as its target
(`PrtConfig.row_neighbours`) and bench_prt's model-free baseline predicts a held-out pixel with it."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from workers.models.prt.gbuffer import SurfaceInputs

# Reflected directions against positions (box diagonals) in the distance, env_lit_objects, default preset,
# the bench's baseline (mean of 16 nearest rows), held-out indirect PSNR against a 1024-spp truth: weight
# 0 / 0.01 / 0.02 / 0.03 / 0.05 / 0.1 / 0.3 / 1 scored 23.4 / 25.6 / 26.1 / 26.2 / 26.1 / 25.2 / 22.7 /
# 21.4 dB (chosen on the held-out truth: if anything, the baseline is flattered).
# prt12b, default preset (96 x 1536 rows), far views, indirect, 1024-spp truth, mean of 16 (32) rows:
# glossy_row, all of whose surfaces are glossy (GGX alpha 0.05-0.25), prefers a larger weight: 0.03 / 0.1 /
# 0.3 24.70 (24.89) / 26.06 (26.56) / 26.14 (26.60) dB (seed 0); a weight 0.03 / clip(alpha, 0.1, 1),
# growing on glossy surfaces only, 24.70 -> 26.35 (26.78) and 24.96 -> 26.43 (26.95) (seeds 0 / 1), but
# env_lit_objects 28.89 (29.35) -> 28.49 (28.97) (seed 0; clip at 0.3: 28.72, glossy_row 26.06). As the
# training targets' neighbours (4000 steps, network far indirect (full)): glossy_row 23.62 (27.04) ->
# 24.47 (28.08) and 23.60 (27.51) -> 23.47 (27.27) (seeds 0 / 1), env_lit_objects 28.68 (31.14) -> 28.60
# (30.80) (seed 0): seed 1 does not confirm, kept 0.03.
DIRECTION_WEIGHT = 0.03
MEAN_CHUNK = 2048  # rows averaged at once (a chunk's k neighbours' rows are gathered into one array)


def _features(inputs: SurfaceInputs, diagonal: float) -> np.ndarray:
    return np.hstack([inputs.position / diagonal, DIRECTION_WEIGHT * inputs.reflected])


def nearest_rows(
    train: SurfaceInputs, query: SurfaceInputs, box: np.ndarray, objects: np.ndarray, k: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per object of `objects` seen by both: (the query pixels on it (n,), their min(k, rows on it)
    nearest training rows (n, k)), indices into `query` and `train`."""
    diagonal = float(np.linalg.norm(box[1] - box[0]))
    out = []
    for obj in objects:
        rows = np.flatnonzero(train.object_id == obj)
        pixels = np.flatnonzero(query.modelled(np.array([obj])))
        if len(rows) == 0 or len(pixels) == 0:
            continue
        kk = min(k, len(rows))
        tree = cKDTree(_features(train.take(rows), diagonal))
        _, nearest = tree.query(_features(query.take(pixels), diagonal), k=kk)
        out.append((pixels, rows[nearest.reshape(len(pixels), kk)]))
    return out


def row_neighbours(inputs: SurfaceInputs, box: np.ndarray, k: int) -> np.ndarray:
    """(P, k) int32: each training row's k nearest rows on its object, itself included (on an object with
    fewer than k rows, the farthest neighbour repeats up to k)."""
    out = np.empty((len(inputs.hit), k), np.int32)
    for pixels, nearest in nearest_rows(inputs, inputs, box, np.unique(inputs.object_id), k):
        out[pixels] = np.pad(nearest, ((0, 0), (0, k - nearest.shape[1])), mode="edge")
    return out


def mean_rows(rows: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(N, J, 3) float64: the mean row of each line of `neighbours` (N, k)."""
    out = np.empty((len(neighbours), *rows.shape[1:]))
    for start in range(0, len(neighbours), MEAN_CHUNK):
        chunk = neighbours[start : start + MEAN_CHUNK]
        out[start : start + len(chunk)] = rows[chunk].mean(axis=1, dtype=np.float64)
    return out
