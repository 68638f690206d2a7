"""Generation quality without a pretrained network: the sliced Wasserstein distance between Laplacian-
pyramid patches of generated and path-traced slab views (Karras et al. 2018's SWD, after Rabin et al.
2011), measured on held-out instances (their own seed stream) rendered under the same labels; and the
conditioning: how the generated density's mean height follows the strand length parameter and its
vertical opacity the strand density parameter.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, stack_views
from workers.models.mesogan.slab import Window, draw_noise, generate_planes
from workers.models.mesogan.train import fake_images
from workers.models.mesogan.volume import HEIGHT_TO_RADIANS

HELD_OUT_SEED_OFFSET = 1 << 20  # held-out instances come from a seed no training batch uses
PATCH = 3
DIRECTIONS = 128


def laplacian_pyramid(images: Tensor, levels: int) -> list[Tensor]:
    pyramid, current = [], images
    for _ in range(levels - 1):
        coarse = F.avg_pool2d(current, 2)
        pyramid.append(current - F.interpolate(coarse, scale_factor=2, mode="nearest"))
        current = coarse
    return [*pyramid, current]


def patches(images: Tensor) -> Tensor:
    """All PATCH x PATCH patches (N, 3 * PATCH^2), each channel normalised over the set."""
    p = F.unfold(images, PATCH).permute(0, 2, 1).reshape(-1, images.shape[1], PATCH * PATCH)
    p = (p - p.mean((0, 2), keepdim=True)) / (p.std((0, 2), keepdim=True) + 1e-8)
    return p.reshape(len(p), -1)


def sliced_wasserstein(a: Tensor, b: Tensor, generator: torch.Generator) -> float:
    """Mean over random unit directions of the 1-D Wasserstein distance of the projected sets."""
    n = min(len(a), len(b))
    directions = F.normalize(torch.randn(a.shape[1], DIRECTIONS, generator=generator), dim=0)
    pa = torch.sort(a[torch.randperm(len(a), generator=generator)[:n]] @ directions, 0).values
    pb = torch.sort(b[torch.randperm(len(b), generator=generator)[:n]] @ directions, 0).values
    return float((pa - pb).abs().mean())


def pyramid_swd(real: Tensor, fake: Tensor, seed: int = 0) -> float:
    """SWD summed over the pyramid's levels (tonemapped images (N, 3, H, W), H >= 8)."""
    generator = torch.Generator().manual_seed(seed)
    levels = max(1, int(np.log2(real.shape[-1] // 4)))
    pairs = zip(laplacian_pyramid(real, levels), laplacian_pyramid(fake, levels), strict=True)
    return sum(sliced_wasserstein(patches(r), patches(f), generator) for r, f in pairs)


def held_out_views(source: SlabSource, count: int):
    """`count` path-traced instances no training batch draws (a seed of their own), as one batch."""
    held_out = SlabSource(source.config, source.seed + HELD_OUT_SEED_OFFSET)
    return stack_views([held_out.instance(j) for j in range(count)])


def generation_scores(model: MesoGAN, batch) -> dict[str, float]:
    """SWD and mean block error of the model's renders of `batch`'s labels, and of a black image."""
    with torch.no_grad():
        torch.manual_seed(0)
        fake = fake_images(model, batch)
    real = batch["image"]
    black = torch.zeros_like(real)
    block = model.config.moment_block
    return {
        "swd": pyramid_swd(real, fake),
        "swd_black": pyramid_swd(real, black + 1e-3 * torch.rand_like(real)),
        "block_error": float((F.avg_pool2d(fake, block) - F.avg_pool2d(real, block)).abs().mean()),
        "block_error_black": float(F.avg_pool2d(real, block).abs().mean()),
    }


def density_profile(model: MesoGAN, structure: Tensor, seed: int, heights: int = 16) -> Tensor:
    """Density (R^2 texels, `heights`) of the slab generated for `structure` (normalised (3,)) at the
    level-0 texels of the training window and `heights` evenly spaced heights in the slab."""
    config = model.config
    window = Window.centred(config.plane_resolution, config.texel)
    generator = torch.Generator().manual_seed(seed)
    latent = torch.randn(1, config.latent_dims, generator=generator)
    with torch.no_grad():
        planes = generate_planes(
            model, config, structure[None], latent, draw_noise(model, config, 1, seed), window
        )
        features = planes[0].flatten(1).T  # (R^2, C) at level 0
        h = (torch.arange(heights) + 0.5) / heights
        f = features[:, None].expand(-1, heights, -1)
        hh = h[None].expand(len(features), -1)
        density, _ = model.decoder.density(f, hh * HEIGHT_TO_RADIANS, torch.zeros_like(hh))
    return density


def mean_height(density: Tensor) -> float:
    """The density-weighted mean height of a profile: a longer pile puts density higher."""
    h = (torch.arange(density.shape[-1]) + 0.5) / density.shape[-1]
    return float((density * h).sum() / density.sum().clamp(min=1e-12))


def vertical_opacity(density: Tensor) -> float:
    """Mean over texels of 1 - transmittance of a vertical ray through the slab (unit height): a denser
    pile hides more of the skin."""
    return float((1 - torch.exp(-density.mean(-1))).mean())


def structure_response(model: MesoGAN, seeds: int = 4) -> dict[str, float]:
    """Mean generated height at the shortest and the longest trained strand length, and vertical opacity
    at the lowest and the highest trained density (other parameters at the middle of their ranges),
    averaged over `seeds` instances: the conditioning figures (a structure label moves geometry its way)."""
    probes = {
        "mean_height_short": ([0.0, 0.5, 0.5], mean_height),
        "mean_height_long": ([1.0, 0.5, 0.5], mean_height),
        "opacity_sparse": ([0.5, 0.0, 0.5], vertical_opacity),
        "opacity_dense": ([0.5, 1.0, 0.5], vertical_opacity),
    }
    return {
        name: float(
            np.mean([measure(density_profile(model, torch.tensor(s), seed)) for seed in range(seeds)])
        )
        for name, (s, measure) in probes.items()
    }
