"""Active exploration's parts (thesis Sec. 5.4-5.5): proposal kernels, Metropolis-Hastings on a known
target, greedy chains (Fig. 5.6), the Adam step-norm oracle, the reuse probability and the patch store."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch
from scipy import stats

from workers.models.explore.config import ExploreConfig
from workers.models.explore.exploration import (
    greedy,
    large_step,
    metropolis,
    patch_origin,
    propose,
    small_step,
)
from workers.models.explore.oracle import adam_step_norms
from workers.models.explore.reuse import PatchStore, reuse_probability

S1, S2 = 1 / 25, 1 / 20


def test_large_steps_are_uniform():
    rng = np.random.default_rng(0)
    states = large_step(rng, (20000, 3))
    for d in range(3):
        assert stats.kstest(states[:, d], "uniform").pvalue > 1e-3


def test_small_steps_are_symmetric_wrapped_moves_of_bounded_size():
    rng = np.random.default_rng(1)
    start = rng.random((50000, 4))
    start[:10] = [0.0, 0.999, 0.01, 0.5]  # near both edges of the torus
    moved = small_step(rng, start, S1, S2)
    assert np.all((moved >= 0) & (moved < 1))
    delta = np.mod(moved - start + 0.5, 1.0) - 0.5  # the shortest displacement on the torus
    assert np.all(np.abs(delta) >= S1 - 1e-12) and np.all(np.abs(delta) <= S2 + 1e-12)
    assert abs(np.mean(delta > 0) - 0.5) < 0.01  # signs balanced
    # symmetric density: the displacement's distribution equals its mirror image
    assert stats.ks_2samp(delta.ravel(), -delta.ravel()).pvalue > 1e-3


def test_proposals_mix_large_and_small_steps_at_p_ls():
    rng = np.random.default_rng(2)
    states = np.full((20000, 2), 0.5)
    proposals, large = propose(rng, states, 0.3, S1, S2)
    assert abs(large.mean() - 0.3) < 0.015
    assert np.all(np.abs(proposals[~large] - 0.5) <= S2 + 1e-12)
    # p_LS = 1 with every proposal accepted is i.i.d. uniform sampling (the baseline)
    proposals, large = propose(rng, states, 1.0, S1, S2)
    assert large.all() and stats.kstest(proposals[:, 0], "uniform").pvalue > 1e-3


def torus_mixture(points: np.ndarray) -> np.ndarray:
    """A 2D target on the torus: two wrapped Gaussians of different weights and widths."""

    def bump(centre, sigma):
        d = np.mod(points - centre + 0.5, 1.0) - 0.5
        return np.exp(-0.5 * (d**2).sum(-1) / sigma**2)

    return 1.0 * bump(np.array([0.25, 0.3]), 0.08) + 0.6 * bump(np.array([0.8, 0.7]), 0.12) + 0.05


def test_metropolis_hastings_with_these_kernels_samples_a_known_target():
    rng = np.random.default_rng(3)
    chains, steps, bins = 256, 3000, 10
    states = rng.random((chains, 2))
    counts = np.zeros((bins, bins))
    for step in range(steps):
        proposals, _ = propose(rng, states, 0.3, S1, S2)
        accept = metropolis(rng, torus_mixture(proposals), torus_mixture(states))
        states = np.where(accept[:, None], proposals, states)
        if step >= 200:
            np.add.at(counts, tuple((states * bins).astype(int).T), 1)
    grid = (np.stack(np.meshgrid(np.arange(200), np.arange(200), indexing="ij"), -1) + 0.5) / 200
    fine = torus_mixture(grid).reshape(bins, 20, bins, 20).sum(axis=(1, 3))
    total_variation = 0.5 * np.abs(counts / counts.sum() - fine / fine.sum()).sum()
    assert total_variation < 0.03, total_variation


def test_greedy_chains_never_accept_a_worse_state_and_find_the_maximum_of_a_fixed_target():
    rng = np.random.default_rng(4)
    states = rng.random((16, 2))
    values = torus_mixture(states)
    for _ in range(400):
        proposals, _ = propose(rng, states, 0.3, S1, S2)
        accept = greedy(torus_mixture(proposals), values)
        states = np.where(accept[:, None], proposals, states)
        new_values = torus_mixture(states)
        assert np.all(new_values >= values)
        values = new_values
    assert values.max() > 0.98 * torus_mixture(np.array([[0.25, 0.3]]))[0]
    assert not greedy(np.nan, 1.0) and not greedy(1.0, 1.0)  # NaN never wins; ties stay


def test_greedy_chains_move_once_the_target_decays_where_they_sit():
    """Fig. 5.6: training lowers the loss where a chain sits, so the chain moves on, and over time the
    states visit the target's cells in proportion to how high the target started."""
    rng = np.random.default_rng(5)
    bins = 8
    initial = rng.gamma(2.0, size=(bins, bins))
    target = initial.copy()
    states = rng.random((16, 2))
    visits = np.zeros((bins, bins))
    for _ in range(6000):
        proposals, _ = propose(rng, states, 0.3, S1, S2)
        cells = tuple((states * bins).astype(int).T)
        proposal_cells = tuple((proposals * bins).astype(int).T)
        accept = greedy(target[proposal_cells], target[cells])
        states = np.where(accept[:, None], proposals, states)
        cells = tuple((states * bins).astype(int).T)
        np.add.at(visits, cells, 1)
        target[cells] *= 0.97  # trained on: the loss there falls
        target += 0.003 * initial  # and slowly comes back as the network changes elsewhere
    assert (visits > 0).all()
    assert stats.spearmanr(initial.ravel(), visits.ravel()).statistic > 0.8


@pytest.mark.parametrize("steps_before", [0, 3])
def test_the_adam_step_norms_are_real_steps_lengths_and_change_nothing(steps_before):
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.LeakyReLU(0.01), torch.nn.Linear(8, 2))
    adam = torch.optim.Adam(model.parameters(), lr=1e-2, betas=(0.9, 0.999), eps=1e-8, weight_decay=1e-3)
    data = torch.randn(16, 4)
    for _ in range(steps_before):
        adam.zero_grad()
        model(data).square().mean().backward()
        adam.step()
    adam.zero_grad(set_to_none=True)
    before_state = copy.deepcopy(adam.state_dict())
    before_params = [p.detach().clone() for p in model.parameters()]
    samples = torch.randn(2, 3, 4)
    per_sample = [
        torch.autograd.grad((model(sample) - 1).abs().mean(), list(model.parameters())) for sample in samples
    ]
    stacked = {p: torch.stack(g) for p, *g in zip(model.parameters(), *per_sample, strict=True)}
    predicted = adam_step_norms(adam, stacked)

    for sample, norm in zip(samples, predicted, strict=True):
        twin = copy.deepcopy(model)
        twin_adam = torch.optim.Adam(twin.parameters(), lr=1e-2, eps=1e-8, weight_decay=1e-3)
        twin_adam.load_state_dict(copy.deepcopy(before_state))
        (twin(sample) - 1).abs().mean().backward()
        twin_adam.step()
        moved = [(a.detach() - b) for a, b in zip(twin.parameters(), before_params, strict=True)]
        real = torch.sqrt(sum((d**2).sum() for d in moved))
        assert float(norm) == pytest.approx(float(real), rel=1e-5)
    assert all(torch.equal(p, q) for p, q in zip(model.parameters(), before_params, strict=True))
    assert all(p.grad is None for p in model.parameters())
    after = adam.state_dict()
    assert after["param_groups"] == before_state["param_groups"]
    for key, state in before_state["state"].items():
        assert all(torch.equal(state[k], after["state"][key][k]) for k in state)


def test_the_reuse_probability_is_open_unit_interval_monotone_and_stable():
    beta = 4.6
    assert reuse_probability(0.2, 0.2, beta) == pytest.approx(0.99, abs=1e-3)
    differences = np.linspace(-1e3, 1e3, 2001)
    p = np.array([reuse_probability(d, 0.0, beta) for d in differences])
    assert np.all((p > 0) & (p < 1)) and np.all(np.isfinite(p))
    assert np.all(np.diff(p) >= 0)
    assert 0 < reuse_probability(np.inf, -np.inf, beta) < 1
    assert 0 < reuse_probability(-np.inf, np.inf, beta) < 1
    assert 0 < reuse_probability(np.nan, 0.1, beta) < 0.01  # an undefined average: render new patches


def test_the_store_never_evicts_a_chains_current_patch():
    store = PatchStore(capacity=3)
    first = store.add({"x": torch.zeros(1)}, large=True)
    store.pin(first)
    ids = [store.add({"x": torch.ones(1)}, large=False) for _ in range(10)]
    assert first in store.patches and len(store) == 3
    assert ids[-1] in store.patches and ids[0] not in store.patches
    store.unpin(first)
    store.add({"x": torch.ones(1)}, large=False)
    assert first not in store.patches


def test_the_store_restores_from_its_state_by_rendering_its_requests_again():
    def render(requests):
        return [{"x": torch.full((1,), float(r))} for r in requests]

    store = PatchStore(capacity=3)
    first = store.add(render([7])[0], large=True, request=7)
    store.pin(first)
    for r in range(5):
        store.add(render([r])[0], large=r % 2 == 0, request=r)
    store.set_weight(first, 0.25)
    state = json.loads(json.dumps(store.state(lambda r: r)))  # as a checkpoint holds it

    restored = PatchStore(capacity=3)
    restored.restore(state, int, render)
    assert list(restored.patches) == list(store.patches) == [first, 4, 5]
    assert all(torch.equal(restored.patches[i]["x"], store.patches[i]["x"]) for i in store.patches)
    assert (restored.weights, restored.large, restored.pins) == (store.weights, store.large, store.pins)
    assert restored.add(render([9])[0], large=False, request=9) == store.next_id
    assert first in restored.patches  # still pinned: a chain's current patch survives the resume


def test_the_store_draws_by_loss_and_uniformly_when_every_loss_is_zero():
    store = PatchStore(capacity=10)
    ids = [store.add({"x": torch.zeros(1)}, large=True) for _ in range(4)]
    for i in ids:
        store.set_weight(i, 0.0)
    rng = np.random.default_rng(0)
    assert set(store.draw(rng, 400)) == set(ids)
    store.set_weight(ids[2], 1.0)
    store.set_weight(ids[3], float("nan"))  # a NaN loss weighs nothing
    assert set(store.draw(rng, 100)) == {ids[2]}
    assert set(store.draw(rng, 400, by_loss=False)) == set(ids)  # `reuse_draw: uniform`


def test_patches_stay_inside_the_image_as_the_resolution_grows():
    config = ExploreConfig(
        patch=8, resolution_start=8, resolution_max=20, resolution_step=4, resolution_every=3
    )
    resolutions = [config.resolution(i) for i in range(40)]
    assert resolutions[0] == 8 and resolutions[-1] == 20 and np.all(np.diff(resolutions) >= 0)
    assert patch_origin(np.array([0.999, 0.999]), 8, 8) == (0, 0)
    for resolution in (8, 13, 20):
        for u in (0.0, 0.5, 0.9999999):
            x, y = patch_origin(np.array([u, u]), resolution, 8)
            assert 0 <= x <= resolution - 8 and 0 <= y <= resolution - 8
    uniform = config.model_copy(update={"exploration": "uniform"})
    assert {uniform.resolution(i) for i in range(40)} == {8}


def test_the_resolution_schedule_is_a_switch_for_either_exploration():
    base = dict(patch=8, resolution_start=8, resolution_max=20, resolution_step=4, resolution_every=3)
    grown = [ExploreConfig(**base).resolution(i) for i in range(40)]
    for exploration in ("active", "uniform"):
        on = ExploreConfig(**base, exploration=exploration, resolution_schedule=True)
        off = ExploreConfig(**base, exploration=exploration, resolution_schedule=False)
        assert [on.resolution(i) for i in range(40)] == grown
        assert {off.resolution(i) for i in range(40)} == {8}
