"""The GAN's two phases on the shared training loop: the discriminator's loss carries R1 on real images;
each phase has its own optimizer, and a run stopped between
checkpoints and resumed (in a process whose torch stream has moved on) ends with the uninterrupted run's
weights, bit for bit, because the latents, the planes' Fourier banks and the ray jitter are drawn from
torch's stream, which checkpoints hold."""

from __future__ import annotations

import pytest
import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig
from workers.models.mesogan.train import DISCRIMINATOR, GENERATOR, discriminator_loss, labels, phases
from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.runtime.threads import torch_threads
from workers.runtime.training import Progress, train_phases

TINY = {
    "image_size": 8,
    "training_spp": 1,
    "pool": 2,
    "batch_size": 2,
    "plane_resolution": 16,
    "train": {"steps": 5, "checkpoint_every": 2, "progress_every": 1},
}


class Interrupted(Exception):
    pass


def test_a_stopped_run_resumes_to_the_uninterrupted_weights(tmp_path):
    config = MesoganConfig.model_validate(PRESETS["quick"] | TINY)
    spec = SourceSpec(SlabSource, SlabSourceConfig(mesogan=config), 3)

    def run(store: CheckpointStore, seed: int, on_progress=None) -> MesoGAN:
        torch.manual_seed(seed)
        model = MesoGAN(config)
        with torch_threads(1):
            train_phases(model, phases(model), InProcessBatches(spec), config.train, store, on_progress)
        return model

    reference = run(CheckpointStore(str(tmp_path / "reference"), keep=10), 3)

    def stop_at_3(event: Progress) -> None:
        if event.step == 3:
            raise Interrupted

    store = CheckpointStore(str(tmp_path / "resumed"), keep=2)
    with pytest.raises(Interrupted):  # after step 3, past the checkpoint at step 2
        run(store, 3, stop_at_3)
    assert store.latest() == 2
    resumed = run(store, 99)  # other initial weights and another torch stream: all must come from step 2

    for (name, a), b in zip(reference.state_dict().items(), resumed.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    final = store.load(config.train.steps)
    assert {*training_state.optimizer_files(GENERATOR), *training_state.optimizer_files(DISCRIMINATOR)} < (
        final.keys()
    )


def test_the_discriminator_loss_adds_r1_on_the_real_images():
    """Non-saturating loss plus gamma / 2 times the squared gradient of the real logits by the real images
    (Mescheder et al. 2018), the same fakes in both."""
    gamma = 2.5
    config = MesoganConfig.model_validate(PRESETS["quick"] | TINY | {"r1_gamma": gamma})
    batch = SlabSource(SlabSourceConfig(mesogan=config), 3).batch(0)
    torch.manual_seed(0)
    model = MesoGAN(config)
    plain = MesoGAN(config.model_copy(update={"r1_gamma": 0.0}))
    plain.load_state_dict(model.state_dict())
    losses = []
    for m in (model, plain):
        torch.manual_seed(1)
        losses.append(discriminator_loss(m, batch))
    real = batch["image"].clone().requires_grad_(True)
    (gradient,) = torch.autograd.grad(model.discriminator(real, labels(batch)).sum(), real)
    r1 = 0.5 * gamma * gradient.pow(2).sum((1, 2, 3)).mean()
    assert r1 > 0 and torch.allclose(losses[0] - losses[1], r1, rtol=1e-4)
