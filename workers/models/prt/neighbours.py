"""Nearest training rows: for a surface point, the k rows of the same object nearest in position (in box
diagonals) and, weighted by a direction weight, reflected direction w_r (the inputs Eq. 4 gives position
and view dependence through).

A row traced at 128 paths is a noisy estimate of the pixel's transport (two independent traces of the same
pixels are 20.3 dB apart under a held-out lighting on env_lit_objects), and its per-wavelet Haar
coefficients, which `transport_weight` supervises, are noisier still. The mean of a row's nearest rows
trades that noise for a blur of the transport over the neighbourhood; training takes it as its target
(`PrtConfig.row_neighbours`, `smoothing_choices`) and bench_prt's model-free baseline predicts a held-out
pixel with it.

How much to average differs by object (noise against how fast transport changes with position and w_r),
and the rows can tell: leave one row out, predict it by the mean of its k nearest other rows, and the
error is the blur's squared bias plus the noise left after averaging plus the row's own noise, the last
the same for every (k, weight). So the (k, weight) with the least leave-one-out error is the one whose
targets are nearest the truth, found without any truth."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from workers.models.prt.gbuffer import SurfaceInputs
from workers.nn.tonemap import srgb_encode

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
# (30.80) (seed 0): seed 1 does not confirm, kept 0.03 for the baseline; training targets choose theirs.
DIRECTION_WEIGHT = 0.03
# The training targets' candidates (`smoothing_choices`). prt13b, seed 0, 2048 training pixels against a
# 1024-spp truth under the held-out lightings (indirect, pooled PSNR of the targets): one (k, weight) for
# every object, glossy_row / env_lit_objects: (16, 0.03) 23.29 / 26.04 dB, (32, 0.03) 24.02 / 26.94, (64,
# 0.03) 23.77 / 27.29, (32, 0.1) 25.11 / 26.70, (64, 0.1) 25.54 / 26.98; per object, the leave-one-out
# choice 25.63 / 27.98 and the best by the truth 25.85 / 28.08. The choices differ by object: glossy_row's
# floor (32, 0.1), panel and white box (128, 0.1), spheres (16-32, 0.1); env_lit_objects' ground and boxes
# (128, 0.03), the chrome sphere (8, 0.03-0.1) (its mirror-sharp transport blurs at 64: 23.7 -> 20.9 dB).
CANDIDATE_NEIGHBOURS = (8, 16, 32, 64, 128)
CANDIDATE_WEIGHTS = (0.03, 0.1, 0.3)
JUDGED_ROWS = 2000  # per object: rows left out in turn to judge the candidates
MEAN_CHUNK = 2048  # rows averaged at once (a chunk's k neighbours' rows are gathered into one array)
JUDGE_CHUNK = 256  # left-out rows whose neighbours are gathered at once


def _features(inputs: SurfaceInputs, diagonal: float, weight: float = DIRECTION_WEIGHT) -> np.ndarray:
    return np.hstack([inputs.position / diagonal, weight * inputs.reflected])


def nearest_rows(
    train: SurfaceInputs,
    query: SurfaceInputs,
    box: np.ndarray,
    objects: np.ndarray,
    k: int,
    weight: float = DIRECTION_WEIGHT,
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
        tree = cKDTree(_features(train.take(rows), diagonal, weight))
        _, nearest = tree.query(_features(query.take(pixels), diagonal, weight), k=kk)
        out.append((pixels, rows[nearest.reshape(len(pixels), kk)]))
    return out


def mean_rows(rows: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(N, J, 3) float64: the mean row of each line of `neighbours` (N, k)."""
    out = np.empty((len(neighbours), *rows.shape[1:]))
    for start in range(0, len(neighbours), MEAN_CHUNK):
        chunk = neighbours[start : start + MEAN_CHUNK]
        out[start : start + len(chunk)] = rows[chunk].mean(axis=1, dtype=np.float64)
    return out


def smoothing_choices(
    inputs: SurfaceInputs,
    rows: np.ndarray,
    box: np.ndarray,
    most: int,
    cubes: np.ndarray,
    rng: np.random.Generator,
) -> dict[int, tuple[int, float]]:
    """Per object: the (k, direction weight) among the candidates (k at most `most`) whose mean of the k
    nearest other rows best predicts `JUDGED_ROWS` left-out rows, by the squared error of their sRGB
    radiance under training lightings `cubes` [L, 6 R^2, 3] (the metric the held-out figures use)."""
    diagonal = float(np.linalg.norm(box[1] - box[0]))
    flat = cubes.reshape(len(cubes), -1, 3)

    def seen(r: np.ndarray) -> np.ndarray:
        return srgb_encode(torch.from_numpy(np.einsum("pjc,ljc->plc", r, flat))).numpy()

    choices = {}
    for obj in np.unique(inputs.object_id):
        own = np.flatnonzero(inputs.object_id == obj)
        ks = [k for k in CANDIDATE_NEIGHBOURS if k <= min(most, len(own) - 1)]
        if not ks:
            choices[int(obj)] = (1, DIRECTION_WEIGHT)
            continue
        judged = rng.choice(own, min(JUDGED_ROWS, len(own)), replace=False)
        truths = seen(rows[judged].astype(np.float64))  # the left-out rows' radiance, for every candidate
        errors = {}
        for weight in CANDIDATE_WEIGHTS:
            tree = cKDTree(_features(inputs.take(own), diagonal, weight))
            _, nearest = tree.query(_features(inputs.take(judged), diagonal, weight), k=ks[-1] + 1)
            nearest = own[nearest]
            # the k nearest others: drop the row itself (or, for a duplicate point, the last)
            others = np.array([n[n != j][: ks[-1]] for n, j in zip(nearest, judged, strict=True)])
            for start in range(0, len(judged), JUDGE_CHUNK):
                chunk = slice(start, start + JUDGE_CHUNK)
                truth = truths[chunk]
                total, counted = np.zeros((len(truth), *rows.shape[1:])), 0
                for k in ks:
                    total += rows[others[chunk, counted:k]].sum(axis=1, dtype=np.float64)
                    counted = k
                    error = float(((seen(total / k) - truth) ** 2).sum())
                    errors[k, weight] = errors.get((k, weight), 0.0) + error
        choices[int(obj)] = min(errors, key=errors.get)
    return choices


def smoothed_rows(
    inputs: SurfaceInputs, rows: np.ndarray, box: np.ndarray, choices: dict[int, tuple[int, float]]
) -> np.ndarray:
    """(P, J, 3) float32: each row's training target, the mean of its object's chosen k nearest rows
    (itself included) under the object's direction weight; `rows` itself if every k is 1."""
    if all(k == 1 for k, _ in choices.values()):
        return rows
    out = np.empty_like(rows)
    for obj, (k, weight) in choices.items():
        for pixels, nearest in nearest_rows(inputs, inputs, box, np.array([obj]), k, weight):
            for start in range(0, len(pixels), MEAN_CHUNK):
                chunk = slice(start, start + MEAN_CHUNK)
                out[pixels[chunk]] = mean_rows(rows, nearest[chunk])
    return out
