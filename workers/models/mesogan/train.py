"""The GAN's two phases on the shared training loop: the discriminator's non-saturating loss with R1 on
real images, and the generator's (with block-mean matching and the structure term), each on its own
named optimizer (`workers.runtime.training.Phase`).

Fakes are rendered under the real batch's labels (structure, colour, light, camera), so the conditional
discriminator judges each pair under the same conditions. Latents and the planes' Fourier banks are drawn
from torch's stream, which checkpoints hold: a resumed run repeats the uninterrupted one.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import Tensor

from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import ON_STRANDS
from workers.models.mesogan.slab import SlabRender, Window, draw_noise, generate_planes, render_slab
from workers.models.mesogan.volume import tonemap
from workers.runtime.sources import Batch
from workers.runtime.training import Phase

DISCRIMINATOR, GENERATOR = "discriminator", "generator"


def labels(batch: Batch) -> Tensor:
    """Every label the discriminator is conditioned on, with the camera position (Sec. 6.2.8)."""
    return torch.cat([batch["structure"], batch["appearance"], batch["light"], batch["camera"] / 8.0], -1)


def fake_views(model: MesoGAN, batch: Batch) -> SlabRender:
    """Renders of freshly generated slabs under the batch's labels, their images tonemapped."""
    config = model.config
    b = batch["image"].shape[0]
    window = Window.centred(config.plane_resolution, config.texel)
    latent = torch.randn(b, config.latent_dims, device=batch["image"].device)
    planes = generate_planes(model, config, batch["structure"], latent, draw_noise(model, config, b), window)
    rendered = render_slab(model, config, planes, window, batch, jitter=True)
    return dataclasses.replace(rendered, image=tonemap(rendered.image))


def discriminator_loss(model: MesoGAN, batch: Batch) -> Tensor:
    with torch.no_grad():
        fake = fake_views(model, batch).image
    real = batch["image"].detach().requires_grad_(model.config.r1_gamma > 0)
    conditions = labels(batch)
    real_logits = model.discriminator(real, conditions)
    loss = F.softplus(model.discriminator(fake, conditions)).mean() + F.softplus(-real_logits).mean()
    if model.config.r1_gamma > 0:
        (gradient,) = torch.autograd.grad(real_logits.sum(), real, create_graph=True)
        loss = loss + 0.5 * model.config.r1_gamma * gradient.pow(2).sum((1, 2, 3)).mean()
    return loss


def generator_loss(model: MesoGAN, batch: Batch) -> Tensor:
    """Non-saturating loss, plus matching each fake's block means to its real twin's (feature matching on
    low-passed images, Salimans et al. 2016): the labels fix the expected colour and shading of a
    block of `moment_block`^2 pixels, so this steadies appearance and lighting early without constraining
    the structure below the block size, which the discriminator judges.

    And the structure term: each fake view's coverage and mean stop height against its real twin's (what
    the labels and the camera fix of the pile's geometry). The real views' brightness hardly follows the
    structure labels (the image mean correlates with density at -0.06, coverage at 0.64, over 40 quick
    instances): strands in each other's shadow are about as dark as the skin, so neither the block means
    nor the discriminator made the generated pile follow them; alone, the GAN grew an opaque pile at
    every label."""
    config = model.config
    views = fake_views(model, batch)
    fake = views.image
    loss = F.softplus(-model.discriminator(fake, labels(batch))).mean()
    if config.mean_color_weight > 0:
        block = config.moment_block
        difference = F.avg_pool2d(fake, block) - F.avg_pool2d(batch["image"], block)
        loss = loss + config.mean_color_weight * difference.abs().mean()
    if config.structure_weight > 0:
        opacity, height = view_structure(batch)
        loss = loss + config.structure_weight * (
            (views.opacity.mean(-1) - opacity).abs().mean()
            + (views.hit_height.mean(-1) - height).abs().mean()
        )
    return loss


def view_structure(batch: Batch) -> tuple[Tensor, Tensor]:
    """Per real view (B,): the fraction of pixel-centre rays that hit a strand, and their first hits' mean
    height (0 on the skin): what `SlabRender.opacity` and `hit_height` average to."""
    heights = batch["hit_height"]
    return (heights > ON_STRANDS).to(heights.dtype).mean(-1), heights.mean(-1)


def phases(model: MesoGAN) -> list[Phase]:
    return [
        Phase(DISCRIMINATOR, discriminator_loss, model.discriminator.parameters()),
        Phase(GENERATOR, generator_loss, model.generator_parameters()),
    ]
