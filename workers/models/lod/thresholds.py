"""Per-voxel optimal visibility thresholds (Weier et al. 2023, Sec. 4.4).

For every occupied voxel at every LoD, fresh segments between points on the voxel's true boundary are
labelled by Embree and classified by the visibility network; a grid search over `candidates` thresholds
t (segment visible iff p >= t) maximises the weighted F-measure of Eq. 6:
(F2 with occlusion as the positive class * n_occ + F1 with visibility positive * n_vis) / (n_occ + n_vis).
F2 on occlusion weighs recall, i.e. missed occluders, which leak light in thin closed geometry.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from workers.models.lod.grid import LodGrid
from workers.models.lod.networks import VisibilityNetwork
from workers.models.lod.sampling import boundary_pairs, first_asset_hits
from workers.render.integrator import PathTracer

VOXELS_PER_CHUNK = 1024


def f_measure(tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, beta: float) -> np.ndarray:
    """F_beta = (1 + b^2) TP / ((1 + b^2) TP + b^2 FN + FP), and 0 where nothing is positive at all."""
    b2 = beta * beta
    numerator = (1 + b2) * tp
    denominator = numerator + b2 * fn + fp
    return np.divide(numerator, denominator, out=np.zeros(np.broadcast(tp, fp).shape), where=denominator > 0)


def best_thresholds(p_visible: np.ndarray, visible: np.ndarray, candidates: int) -> np.ndarray:
    """Thresholds (V,) maximising Eq. 6 per row of predictions/labels (V, S). Ties go to the candidate
    nearest 0.5, so voxels whose samples are all of one class keep a neutral threshold where possible."""
    v, _ = p_visible.shape
    grid = np.linspace(0.0, 1.0, candidates)
    # Candidate k classifies a sample as occluded iff p < grid[k], i.e. iff k >= (#candidates <= p).
    rank = np.searchsorted(grid, p_visible, side="right")  # in 1..candidates
    rows = np.repeat(np.arange(v), p_visible.shape[1])
    occluded = ~visible.reshape(-1)
    hist_occ = np.bincount(
        rows[occluded] * (candidates + 1) + rank.reshape(-1)[occluded], minlength=v * (candidates + 1)
    )
    hist_vis = np.bincount(
        rows[~occluded] * (candidates + 1) + rank.reshape(-1)[~occluded], minlength=v * (candidates + 1)
    )
    # Predicted occluded at candidate k: rank <= k.
    tp_occ = np.cumsum(hist_occ.reshape(v, candidates + 1), axis=1)[:, :candidates]
    fp_occ = np.cumsum(hist_vis.reshape(v, candidates + 1), axis=1)[:, :candidates]
    n_occ = occluded.reshape(v, -1).sum(1, keepdims=True)
    n_vis = visible.sum(1, keepdims=True)
    fn_occ = n_occ - tp_occ
    f2_occ = f_measure(tp_occ, fp_occ, fn_occ, 2.0)
    f1_vis = f_measure(n_vis - fp_occ, fn_occ, fp_occ, 1.0)  # visible positive: TP, FP, FN
    score = (f2_occ * n_occ + f1_vis * n_vis) / np.maximum(n_occ + n_vis, 1)
    best = score.max(1, keepdims=True)
    tie_break = np.where(score >= best - 1e-12, -np.abs(grid - 0.5), -np.inf)
    return grid[tie_break.argmax(1)].astype(np.float32)


def optimise_thresholds(
    grid: LodGrid,
    network: VisibilityNetwork,
    tracer: PathTracer,
    samples: int,
    candidates: int,
    rng: np.random.Generator,
    on_level: Callable[[int], None] | None = None,
) -> dict[str, float]:
    """Fill `grid.thresholds` at every level; returns the mean accuracy gain over a fixed 0.5."""
    device = next(network.parameters()).device
    gains = []
    for level in range(grid.levels):
        cells = grid.cells(level)
        thresholds = np.empty(len(cells), np.float32)
        for start in range(0, len(cells), VOXELS_PER_CHUNK):
            chunk = cells[start : start + VOXELS_PER_CHUNK]
            repeated = np.repeat(chunk, samples, axis=0)
            pairs = boundary_pairs(grid, np.full(len(repeated), level), repeated, rng, grow=0.0)
            occluded, _ = first_asset_hits(tracer, pairs)
            with torch.no_grad():
                logits = network(
                    torch.from_numpy(grid.normalize(pairs.p_o)).float().to(device),
                    torch.from_numpy(grid.normalize(pairs.p_i)).float().to(device),
                )
            p = torch.sigmoid(logits).cpu().numpy().reshape(len(chunk), samples)
            visible = ~occluded.reshape(len(chunk), samples)
            chosen = best_thresholds(p, visible, candidates)
            thresholds[start : start + len(chunk)] = chosen
            gains.append(_accuracy_gain(p, visible, chosen))
        grid.thresholds[level] = thresholds
        if on_level is not None:
            on_level(level)
    return {"threshold_accuracy_gain": float(np.mean(gains)) if gains else 0.0}


def _accuracy_gain(p: np.ndarray, visible: np.ndarray, thresholds: np.ndarray) -> float:
    """Classification accuracy with the chosen thresholds minus with a fixed 0.5 (on the search samples)."""
    chosen = ((p >= thresholds[:, None]) == visible).mean()
    fixed = ((p >= 0.5) == visible).mean()
    return float(chosen - fixed)
