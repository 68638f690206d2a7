"""The explore network and its training loop: position preconditioning, per-pixel independence, the
emission rule, deterministic exploration for a seed, and finite training on fireflies and mirrors."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch

from workers.models.explore.config import PRESETS, ExploreConfig
from workers.models.explore.evaluate import RGSS, network_image, pixel_offsets
from workers.models.explore.explorer import Explorer, patch_losses
from workers.models.explore.features import BUFFER_CHANNELS
from workers.models.explore.network import PixelGenerator
from workers.models.explore.source import PatchRequest, PatchSource, PatchSourceConfig
from workers.nn.configs import HashGridConfig, MLPConfig
from workers.runtime.samplers import InProcessRenders
from workers.runtime.sources import SourceSpec
from workers.runtime.training import TrainConfig, train_phases
from workers.scene.format.spec import SceneSpec
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

K = 3
QUICK = ExploreConfig.model_validate(PRESETS["quick"])


def network(grid: HashGridConfig | None = None) -> PixelGenerator:
    torch.manual_seed(0)
    return PixelGenerator(K, MLPConfig(width=16, depth=2, activation="leaky_relu"), grid)


SMALL_GRID = HashGridConfig(levels=4, base_resolution=4, per_level_scale=2.0, log2_table_size=8)


@pytest.mark.parametrize("grid", [None, SMALL_GRID])
def test_the_first_layer_reads_position_only(grid):
    model = network(grid)
    features = torch.rand(5, BUFFER_CHANNELS + K, requires_grad=True)
    model.first(model.encode_position(features[:, :3])).sum().backward()
    first_only = features.grad.clone()
    assert first_only[:, 3:].abs().max() == 0 and first_only[:, :3].abs().max() > 0
    features.grad = None
    model(features, torch.zeros(5, 3)).sum().backward()
    assert features.grad[:, 3:].abs().max() > 0  # the hidden layers re-read every buffer and v


def test_pixels_are_independent():
    model = network()
    features, emission = torch.rand(6, 7, BUFFER_CHANNELS + K), torch.rand(6, 7, 3) * 0.1
    out = model(features, emission)
    order = torch.randperm(42)
    shuffled = model(features.reshape(42, -1)[order], emission.reshape(42, 3)[order])
    torch.testing.assert_close(shuffled, out.reshape(42, 3)[order])


def test_bright_emitters_pass_through_and_dim_ones_add():
    model = network()
    features = torch.rand(2, BUFFER_CHANNELS + K)
    dark = model(features, torch.zeros(2, 3))
    emission = torch.tensor([[20.0, 15.0, 8.0], [0.3, 0.2, 0.1]])
    out = model(features, emission)
    torch.testing.assert_close(out[0], torch.log1p(emission[0]))
    torch.testing.assert_close(out[1], dark[1] + torch.log1p(emission[1]))


def test_the_loss_is_finite_on_fireflies_black_and_huge_targets():
    model = network()
    batch = {
        "features": torch.rand(3, 8, 8, BUFFER_CHANNELS + K),
        "emission": torch.zeros(3, 8, 8, 3),
        "target": torch.zeros(3, 8, 8, 3),
    }
    batch["target"][0, 3, 3] = 1e30  # a firefly
    batch["target"][1] = 1e6
    losses = patch_losses(model, batch, 2.0)
    losses.mean().backward()
    assert torch.isfinite(losses).all()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())


def explore_run(
    scene: SceneSpec, seed: int, steps: int, **overrides
) -> tuple[Explorer, list, PixelGenerator]:
    config = QUICK.model_copy(update=overrides)
    spec = SourceSpec(PatchSource, PatchSourceConfig(SceneRef(scene), config), seed)
    torch.manual_seed(seed)
    model = PixelGenerator.of(config, spec.build().dimensions)
    explorer = Explorer(config, model.dimensions, model, seed)
    losses, snapshots, ages = [], [], []

    def loss(m, batch):
        snapshots.append([p.detach().clone() for p in m.parameters()])
        ages.append([chain.age for chain in explorer.chains])
        value = explorer.loss(m, batch)
        losses.append(float(value.detach()))
        return value

    with InProcessRenders(spec) as renders, explorer.open(renders) as batches:
        phase = dataclasses.replace(explorer.phase(), loss=loss)
        train_phases(model, [phase], batches, TrainConfig(steps=steps, schedule={"lr": 3e-3}, eps=1e-8))
    explorer.snapshots, explorer.ages = snapshots, np.array(ages)
    return explorer, losses, model


def test_exploration_is_deterministic_for_a_seed_and_trains_on_every_rendered_patch():
    scene = get_builtin("mirror_variable")
    a, losses_a, model_a = explore_run(scene, 3, 12, bootstrap=3, spp=2)
    _, losses_b, model_b = explore_run(scene, 3, 12, bootstrap=3, spp=2)
    assert losses_a == losses_b
    assert all(torch.equal(p, q) for p, q in zip(model_a.parameters(), model_b.parameters(), strict=True))
    stats = a.statistics()
    assert stats["patches_rendered"] >= 3 * QUICK.chains
    assert 0 < stats["final_reuse_probability"] < 1
    assert 0 <= stats["acceptance_rate"] <= 1
    # every rendered patch is trained on at least once: the store saw a loss for each
    assert all(w != 1.0 for w in a.store.weights.values())


def test_the_mean_chain_age_counts_the_generations_chains_keep_their_states():
    explorer, _, _ = explore_run(get_builtin("mirror_variable"), 4, 16, bootstrap=16, spp=1)
    assert explorer.ages.max() > 2  # greedy chains keep states for generations
    assert explorer.statistics()["mean_chain_age"] == pytest.approx(explorer.ages.mean())
    rises = np.diff(explorer.ages, axis=0)
    assert np.all((rises == 1) | (explorer.ages[1:] == 0))  # one more generation, or a move


def test_the_average_is_the_moving_average_of_the_weights_each_step_trained_from():
    explorer, _, model = explore_run(
        get_builtin("mirror_variable"), 2, 6, bootstrap=2, spp=1, average_decay=0.5
    )
    expected = [p.clone() for p in explorer.snapshots[0]]
    for n, snapshot in enumerate(explorer.snapshots):
        decay = min(0.5, (1 + n) / (10 + n))
        expected = [decay * e + (1 - decay) * w for e, w in zip(expected, snapshot, strict=True)]
    for mean, value in zip(explorer.average.parameters(), expected, strict=True):
        torch.testing.assert_close(mean, value)
    assert not all(
        torch.equal(a, b) for a, b in zip(explorer.average.parameters(), model.parameters(), strict=True)
    )


def test_training_stays_finite_on_a_near_mirror_and_fireflies():
    scene = get_builtin("mirror_variable")
    mirror = scene.materials["mirror"].model_copy(update={"roughness": 1e-4})
    near_mirror = scene.model_copy(update={"materials": {**scene.materials, "mirror": mirror}})
    _, losses, model = explore_run(near_mirror, 1, 10, bootstrap=10, spp=1, max_depth=6)
    assert np.all(np.isfinite(losses))
    assert all(torch.isfinite(p).all() for p in model.parameters())


def test_the_targets_are_each_patchs_loss_times_its_adam_step_of_the_layers():
    model = network(SMALL_GRID)
    adam = torch.optim.Adam(model.parameter_groups(10.0), lr=1e-3)
    patches = [
        {"features": torch.rand(8, 8, BUFFER_CHANNELS + K), "emission": torch.zeros(8, 8, 3),
         "target": torch.rand(8, 8, 3) * 2}
        for _ in range(3)
    ]  # fmt: skip
    for _ in range(2):  # a warm Adam
        adam.zero_grad()
        patch_losses(
            model, {k: torch.stack([p[k] for p in patches]) for k in patches[0]}, 2.0
        ).mean().backward()
        adam.step()
    adam.zero_grad(set_to_none=True)
    log1p = {"loss_ssim_weight": 1.0, "target_space": "log1p"}  # f on the training loss
    explorer = Explorer(QUICK.model_copy(update=log1p), K, model, 0)
    assert np.allclose(
        explorer.targets(patches),
        [float(patch_losses(model, {k: v[None] for k, v in p.items()}, 2.0)[0].detach()) for p in patches],
        rtol=1e-5,
    )
    explorer.attach(adam)
    expected = []
    for patch in patches:  # a real step of a copy of the model and of its Adam
        stepped = copy.deepcopy(model)
        stepped_adam = torch.optim.Adam(stepped.parameter_groups(10.0), lr=1e-3)
        stepped_adam.load_state_dict(copy.deepcopy(adam.state_dict()))  # it would share the moments
        loss = patch_losses(stepped, {k: v[None] for k, v in patch.items()}, 2.0)[0]
        loss.backward()
        stepped_adam.step()
        assert not torch.equal(stepped.grid.table, model.grid.table)  # the real step moves the table too
        moved = [  # but f measures the layers' displacement (the thesis's network; `Explorer.targets`)
            (a - b).double() for a, b in zip(stepped.layers().values(), model.layers().values(), strict=True)
        ]
        length = torch.sqrt(sum(d.square().sum() for d in moved)).detach()
        expected.append(float(loss.detach()) * float(length))
    np.testing.assert_allclose(explorer.targets(patches), expected, rtol=1e-4)
    assert all(p.grad is None for p in model.parameters())


def test_frames_average_the_network_at_each_pixels_points():
    source = PatchSource(PatchSourceConfig(SceneRef(get_builtin("mirror_variable")), QUICK), 0)
    model = PixelGenerator.of(QUICK, source.dimensions)
    v = np.full(source.dimensions, 0.5)
    tracer = source.tracer.at(v)
    camera = tracer.scene.spec.camera
    grid, _ = network_image(model, tracer, camera, source.box, v, 10, 8, 2)
    fine, _ = network_image(model, tracer, camera, source.box, v, 20, 16, 1)  # the 2 x 2 grid's centres
    np.testing.assert_allclose(grid, fine.reshape(8, 2, 10, 2, 3).mean(axis=(1, 3)), rtol=1e-4, atol=1e-5)
    offsets = pixel_offsets(RGSS)
    assert len(np.unique(offsets[:, 0])) == len(np.unique(offsets[:, 1])) == 4  # 4 rooks
    assert np.all((offsets > 0) & (offsets < 1))
    rotated, _ = network_image(model, tracer, camera, source.box, v, 10, 8, RGSS)
    assert np.all(np.isfinite(rotated)) and not np.allclose(rotated, grid)
    with pytest.raises(ValueError, match=r"^antialiasing: "):
        pixel_offsets(0)


def test_patches_and_frames_through_mirrors_demodulate_and_remodulate():
    """With `mirror_bounces`, a patch's target is the traced radiance over the mirrors' throughput (the
    same render: the buffers change, not the paths), and a frame is the network's radiance times it."""
    config = QUICK.model_copy(update={"mirror_bounces": 1})
    sources = [
        PatchSource(PatchSourceConfig(SceneRef(get_builtin("mirror_variable")), c), 0)
        for c in (QUICK.model_copy(update={"mirror_bounces": 0}), config)
    ]
    request = PatchRequest((0.5,) * sources[0].dimensions, 32, 8, 8, seed=7)  # the mirror's centre
    plain, followed = (s.render(request) for s in sources)
    ratio = plain["target"] / followed["target"].clamp_min(1e-12)
    mirrored = ~torch.isclose(plain["features"], followed["features"]).all(dim=-1)
    assert mirrored.float().mean() > 0.3  # the room in the mirror (the rest of it shows the open front)
    lit = mirrored & (plain["target"] > 0).all(dim=-1)
    torch.testing.assert_close(ratio[lit], torch.full_like(ratio[lit], 0.9))
    torch.testing.assert_close(plain["target"][~mirrored], followed["target"][~mirrored])
    model = PixelGenerator.of(config, sources[1].dimensions)
    with torch.no_grad():  # a network that answers 1 everywhere
        model.output.weight.zero_()
        model.output.bias.fill_(float(np.log1p(1.0)))
    v = np.full(sources[1].dimensions, 0.5)
    tracer = sources[1].tracer.at(v)
    frame, _ = network_image(model, tracer, tracer.scene.spec.camera, sources[1].box, v, 16, 16, 1, 1)
    for value in (1.0, 0.9):  # the room, and the room in the mirror
        assert np.isclose(frame, value, atol=1e-5).all(axis=-1).sum() > 20, value
    emitted = frame.reshape(-1, 3)[frame.sum(axis=-1).argmax()]  # the light, and its reflection
    assert np.isclose(frame, 0.9 * emitted, rtol=1e-5).all(axis=-1).any()


@pytest.mark.parametrize("draw", ["loss", "uniform"])
def test_reuse_draws_stored_patches_by_the_configured_rule(draw):
    model = network()
    explorer = Explorer(QUICK.model_copy(update={"reuse_draw": draw}), K, model, 0)
    patch = {k: torch.zeros(4, 4, 3) for k in ("features", "emission", "target")}
    ids = [explorer.store.add(patch, large=True) for _ in range(4)]
    for i in ids:
        explorer.store.set_weight(i, 1.0 if i == ids[0] else 0.0)
    rng = np.random.default_rng(0)
    drawn = {int(i) for _ in range(50) for i in explorer._reuse(rng)["patch_id"]}
    assert drawn == ({ids[0]} if draw == "loss" else set(ids))


@pytest.mark.parametrize("space", ["log1p", "display"])
def test_the_target_judges_patches_in_the_configured_space(space):
    """A bright emitter (passed through, radiance 3) against a target of 5: far apart in log1p radiance,
    the same white once displayed, so f sees no error there in display space."""
    explorer = Explorer(QUICK.model_copy(update={"target_space": space}), K, network(), 0)
    patch = {
        "features": torch.zeros(8, 8, BUFFER_CHANNELS + K),
        "emission": torch.full((8, 8, 3), 3.0),
        "target": torch.full((8, 8, 3), 5.0),
    }
    (value,) = explorer.targets([patch])
    assert (value == 0.0) == (space == "display")
    assert value > 0.5 or space == "display"  # 2 |log1p 3 - log1p 5| = 0.81
