"""Per-voxel optimal visibility thresholds (Weier et al. 2023, Sec. 4.4, Eq. 5-6).

The vectorised search (`best_thresholds`: histograms and cumulative sums) is checked against Eq. 6
evaluated directly from precision and recall, candidate by candidate; and `optimise_thresholds` end to end
with an oracle classifier whose probabilities are right but shifted (every segment p >= 0.8): a fixed 0.5
calls everything visible, the optimal thresholds must separate the classes exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.support.lod import OracleVisibility
from workers.models.lod.grid import LodGrid
from workers.models.lod.sampling import asset_tracer, asset_triangles, boundary_pairs, first_asset_hits
from workers.models.lod.thresholds import best_thresholds, f_measure, optimise_thresholds
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene


def eq5(tp: int, fp: int, fn: int, beta: float) -> float:
    """F_beta from precision and recall (Eq. 5); 0 when either is undefined or zero."""
    if tp == 0:
        return 0.0
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    return (1 + beta**2) * precision * recall / (beta**2 * precision + recall)


def eq6_scores(p: np.ndarray, visible: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Eq. 6 for one voxel's samples at every candidate threshold (visible iff p >= t)."""
    scores = []
    n_occ, n_vis = int((~visible).sum()), int(visible.sum())
    for t in grid:
        predicted_visible = p >= t
        tp_occ = int((~predicted_visible & ~visible).sum())
        fp_occ = int((~predicted_visible & visible).sum())
        fn_occ = int((predicted_visible & ~visible).sum())
        tp_vis = int((predicted_visible & visible).sum())
        f2_occ = eq5(tp_occ, fp_occ, fn_occ, 2.0)
        f1_vis = eq5(tp_vis, fn_occ, fp_occ, 1.0)
        scores.append((f2_occ * n_occ + f1_vis * n_vis) / (n_occ + n_vis))
    return np.array(scores)


def test_f_measure_values_and_zero_denominators():
    # TP 8, FP 2, FN 4: precision 0.8, recall 2/3.
    assert f_measure(np.array(8), np.array(2), np.array(4), 1.0) == pytest.approx(eq5(8, 2, 4, 1.0))
    assert f_measure(np.array(8), np.array(2), np.array(4), 2.0) == pytest.approx(40 / 58)
    with np.errstate(all="raise"):  # no division warnings where nothing is positive at all
        out = f_measure(np.array([0, 0, 5]), np.array([0, 3, 0]), np.array([0, 0, 0]), 2.0)
    np.testing.assert_array_equal(out, [0.0, 0.0, 1.0])


def test_vectorised_search_agrees_with_eq6_by_brute_force():
    rng = np.random.default_rng(31)
    candidates = 100
    grid = np.linspace(0.0, 1.0, candidates)
    v, s = 40, 64
    visible = rng.random((v, s)) < rng.uniform(0.05, 0.95, (v, 1))
    # Overlapping class distributions of varying quality, some probabilities exactly on candidates and on
    # 0 and 1 (the comparison p >= t at ties), one row all visible and one all occluded.
    p = np.clip(np.where(visible, rng.normal(0.65, 0.2, (v, s)), rng.normal(0.4, 0.2, (v, s))), 0, 1)
    p[:, :6] = grid[rng.integers(0, candidates, (v, 6))]
    p[0, :3], p[1, :3] = 0.0, 1.0
    visible[2], visible[3] = True, False
    chosen = best_thresholds(p, visible, candidates)
    assert chosen.shape == (v,) and chosen.dtype == np.float32
    for row in range(v):
        scores = eq6_scores(p[row], visible[row], grid)
        k = int(np.flatnonzero(grid.astype(np.float32) == chosen[row])[0])
        assert scores[k] == pytest.approx(scores.max(), abs=1e-12), row
        # The documented tie-break: of the maximisers, the one nearest 0.5 (first on a tie).
        best = np.flatnonzero(scores >= scores.max() - 1e-12)
        assert k == best[np.argmin(np.abs(grid[best] - 0.5))], row


def test_separable_classes_get_a_threshold_between_them():
    rng = np.random.default_rng(32)
    s = 200
    visible = rng.random((3, s)) < 0.6
    # Row 0: a well calibrated network; rows 1, 2: the classes separable but both above 0.5 or both below
    # (a hash collision shifting a voxel's probabilities): 0.5 would misclassify a whole class.
    p = np.empty((3, s))
    p[0] = np.where(visible[0], rng.uniform(0.6, 0.95, s), rng.uniform(0.05, 0.4, s))
    p[1] = np.where(visible[1], rng.uniform(0.86, 0.95, s), rng.uniform(0.7, 0.8, s))
    p[2] = np.where(visible[2], rng.uniform(0.3, 0.45, s), rng.uniform(0.05, 0.2, s))
    t = best_thresholds(p, visible, 100)
    for row in range(3):
        assert p[row][~visible[row]].max() < t[row] <= p[row][visible[row]].min(), row
        assert np.array_equal(p[row] >= t[row], visible[row])
    assert abs(t[0] - 0.5) < 0.011  # the neutral threshold among the many perfect ones
    assert 0.8 < t[1] <= 0.86 and 0.2 < t[2] <= 0.3


def test_voxels_of_one_class_get_a_sensible_threshold_without_dividing_by_zero():
    p = np.array([[0.7, 0.9, 0.6, 0.99], [0.2, 0.3, 0.1, 0.35], [0.7, 0.9, 0.6, 0.99], [0.2, 0.3, 0.1, 0.35]])
    visible = np.array([[True] * 4, [True] * 4, [False] * 4, [False] * 4])
    with np.errstate(all="raise"):
        t = best_thresholds(p, visible, 100)
    assert np.all(np.isfinite(t))
    # All visible: every sample stays visible (t <= min p), and no lower than needed: the neutral ~0.5 when
    # min p >= 0.5, else the largest candidate below min p.
    assert np.all((p[0] >= t[0]) & (p[1] >= t[1]))
    assert abs(t[0] - 0.5) < 0.011 and 0.09 < t[1] <= 0.1
    # All occluded: every sample occluded (p < t), and the neutral ~0.5 when max p < 0.5.
    assert np.all((p[2] < t[2]) & (p[3] < t[3]))
    assert abs(t[3] - 0.5) < 0.011 and t[2] > 0.99


def closed_box_asset(resolutions):
    scene = compile_scene(get_builtin("closed_box"))
    tracer = asset_tracer(scene, ["box"])
    triangles = scene.positions[asset_triangles(scene, ["box"])].astype(np.float64)
    return scene, tracer, LodGrid.build(triangles, resolutions)


def test_optimise_thresholds_separates_a_shifted_oracle():
    _, tracer, grid = closed_box_asset([8, 4])
    oracle = OracleVisibility(grid, tracer)
    done = []
    gains = optimise_thresholds(
        grid, oracle, tracer, 64, 100, np.random.default_rng(33), on_level=done.append
    )
    assert done == [0, 1]
    assert gains["threshold_accuracy_gain"] > 0.05  # fixed 0.5 calls the occluded segments visible
    rng = np.random.default_rng(34)
    for level in range(grid.levels):
        t = grid.thresholds[level]
        assert len(t) == len(grid.keys[level]) and t.dtype == np.float32
        assert np.mean((t > 0.8) & (t <= 0.9)) > 0.5  # most voxels see both classes: t separates them
        # Fresh segments through the level's voxels: the chosen thresholds classify them (almost) perfectly,
        # a fixed 0.5 calls every occluded one visible.
        cells = np.repeat(grid.cells(level), 50, axis=0)
        pairs = boundary_pairs(grid, np.full(len(cells), level), cells, rng, 0.0)
        occluded, _ = first_asset_hits(tracer, pairs)
        with torch.no_grad():
            logits = oracle(
                torch.from_numpy(grid.normalize(pairs.p_o)), torch.from_numpy(grid.normalize(pairs.p_i))
            )
        p = torch.sigmoid(logits).numpy()
        assert 0.2 < occluded.mean() < 0.8
        assert np.mean((p >= grid.threshold(level, cells)) == ~occluded) > 0.99
        assert np.mean((p >= 0.5) == ~occluded) == pytest.approx(1 - occluded.mean())
