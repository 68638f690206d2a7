"""The appearance output of `lod` cannot collapse (issue 12): on a closed, smooth, dark object whose
throughput targets are small (~0.01) and mostly 0 (light behind the surface), both outputs learn the
targets' mean. Before the fix the log output fell from exp(0) = 1 to phi ~ 1e-3 of the targets within
a few dozen steps at the paper's learning rate and never came back (a scanned asset: phi = 3e-26, every
LoD black); this test failed on that code with mean phi 3e-6 against a target mean of 0.012 (linear: 0.0121).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from workers.models.lod.artifact import build_networks
from workers.models.lod.config import LodConfig
from workers.models.lod.grid import LodGrid
from workers.models.lod.networks import MIN_LOG_THROUGHPUT, PRIOR_THROUGHPUT, AppearanceNetwork
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_triangles
from workers.models.lod.train import RELATIVE_SCALE, lod_loss, positive_relative_l2
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import train
from workers.scene.format.spec import ConstantBackground, Diffuse, ProceduralShape, SceneObject, SceneSpec
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.reference import SceneRef

STEPS = 150
HELD_OUT_BATCHES = 4


def dark_blob() -> SceneSpec:
    """A closed, smooth, noise-displaced sphere (3k triangles) of albedo 0.15."""
    shape = ProceduralShape(
        generator="displaced_sphere", params={"seed": 2, "resolution": 40, "amplitude": 0.15, "octaves": 3}
    )
    return SceneSpec(
        materials={"dark": Diffuse(reflectance=(0.15, 0.15, 0.15))},
        objects=[SceneObject(name="blob", shape=shape, material="dark")],
        environment=ConstantBackground(),
    )


def small_config(output: str) -> LodConfig:
    small = {"grid": {"features_per_level": 2, "log2_table_size": 14}, "mlp": {"width": 64, "depth": 2}}
    return LodConfig(
        objects=["blob"],
        finest_resolution=32,
        appearance=small,
        visibility=small,
        sh_degree=4,
        batch_size=2048,
        appearance_output=output,
        train={"steps": STEPS, "schedule": {"lr": 0.005}, "checkpoint_every": STEPS, "progress_every": STEPS},
        samplers=0,
    )


def tiny_appearance(output: str) -> AppearanceNetwork:
    return AppearanceNetwork(small_config(output), octaves=1, coarsest=8)


def directions(n: int, seed: int) -> torch.Tensor:
    v = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed))
    return v / v.norm(dim=1, keepdim=True)


# The log output is the default and the one that collapsed; linear, the comparison, runs with `make test-all`.
@pytest.mark.parametrize("output", [pytest.param("linear", marks=pytest.mark.slow), "log"])
def test_training_on_a_dark_closed_object_learns_the_mean_throughput(output):
    config = small_config(output)
    spec = dark_blob()
    scene = compile_scene(spec)
    grid = LodGrid.build(
        scene.positions[asset_triangles(scene, ["blob"])].astype(np.float64), config.resolutions
    )
    source = LodSourceConfig(SceneRef(spec), ["blob"], config, grid.arrays())
    torch.manual_seed(0)
    networks = build_networks(config, grid)
    train(networks, lod_loss, InProcessBatches(SourceSpec(LodSource, source, 0)), config.train)

    held_out = LodSource(source, seed=1)
    phi, target = [], []
    with torch.no_grad():
        for index in range(HELD_OUT_BATCHES):
            batch = held_out.batch(index)
            phi.append(networks.appearance(batch["app_centre"], batch["app_wo"], batch["app_wi"]))
            target.append(batch["app_value"])
    phi, target = torch.cat(phi).clamp(min=0), torch.cat(target)
    assert 0.003 < target.mean() < 0.03 and 0.2 < (target.sum(1) > 0).float().mean() < 0.8  # the setting
    assert 0.5 < phi.mean() / target.mean() < 2.0


def test_the_log_output_starts_at_the_prior_mean_throughput():
    """Not at exp(0) = 1, 20x above typical targets, whence the first steps overshoot."""
    network = tiny_appearance("log")
    n = 4096
    centres = torch.rand(n, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        phi = network(centres, directions(n, 1), directions(n, 2))
    assert 0.5 < phi.mean() / PRIOR_THROUGHPUT < 2.0


@pytest.mark.parametrize("log_p", [-5.0, -10.0, -30.0])
def test_the_log_output_is_pulled_up_towards_its_targets_however_far_it_fell(log_p):
    """dL/dr = 2 (p - t) / (p + s) -> -2 t / s as p -> 0 (Lehtinen's normaliser gives ~ -2 t p / s^2)."""
    r = torch.tensor([log_p], requires_grad=True)
    target = torch.tensor([0.05])
    positive_relative_l2(torch.exp(r), target).backward()
    p = math.exp(log_p)
    assert r.grad.item() == pytest.approx(2 * (p - 0.05) / (p + RELATIVE_SCALE), rel=1e-4)
    assert r.grad.item() < -0.5


def test_positive_relative_l2_is_unbiased_on_noisy_targets():
    """Targets 0 or 2 mu with equal odds: the expected gradient is zero exactly at p = mu."""
    mu = 0.02
    targets = torch.tensor([0.0, 2 * mu])

    def mean_gradient(p: float) -> float:
        r = torch.full((2,), math.log(p), requires_grad=True)
        positive_relative_l2(torch.exp(r), targets).backward()
        return r.grad.sum().item()

    assert mean_gradient(mu) == pytest.approx(0.0, abs=1e-6)
    assert mean_gradient(mu / 2) < 0 < mean_gradient(2 * mu)


def test_the_floor_bounds_the_log_output_but_passes_its_gradient():
    network = tiny_appearance("log")
    with torch.no_grad():
        network.mlp.layers[-2].bias.fill_(-60.0)  # far below the floor
    n = 64
    phi = network(torch.rand(n, 3), directions(n, 1), directions(n, 2))
    assert torch.allclose(phi, torch.full_like(phi, math.exp(MIN_LOG_THROUGHPUT)))
    positive_relative_l2(phi, torch.full_like(phi, 0.05)).backward()
    assert network.mlp.layers[-2].bias.grad.max() < 0  # descent raises the output
