"""Generation quality without a pretrained network: the sliced Wasserstein distance between Laplacian-
pyramid patches of generated and path-traced slab views (Karras et al. 2018's SWD, after Rabin et al.
2011), measured on held-out instances (their own seed stream) rendered under the same labels; and the
conditioning: how the coverage of generated views follows the strand density and curliness labels and the
height where their rays stop the strand length label, beside the same figures of real strands.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from workers.models.mesogan.config import STRUCTURE_RANGES
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, View, first_hit_heights, instance_tracer, stack_views
from workers.models.mesogan.train import fake_views, view_structure
from workers.scene.spec import Structure

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


def held_out_views(source: SlabSource, count: int, coarse: bool | None = None):
    """`count` path-traced instances no training batch draws (a seed of their own), as one batch; with
    `coarse`, only the coarse (or only the fine) views among them (`sampling`): the far views whose
    pixels read the coarse mip levels, where the thesis's no-mipmapping ablation aliases."""
    held_out = SlabSource(source.config, source.seed + HELD_OUT_SEED_OFFSET)
    size = source.config.mesogan.image_size
    ids = (j for j in itertools.count() if coarse is None or (held_out.draw(j).camera.width < size) == coarse)
    return stack_views([held_out.instance(j) for j in itertools.islice(ids, count)], size)


def generation_scores(model: MesoGAN, batch) -> dict[str, float]:
    """SWD and mean block error of the model's renders of `batch`'s labels, and of a black image."""
    with torch.no_grad():
        torch.manual_seed(0)
        fake = fake_views(model, batch).image
    real = batch["image"]
    black = torch.zeros_like(real)
    block = model.config.moment_block
    return {
        "swd": pyramid_swd(real, fake),
        "swd_black": pyramid_swd(real, black + 1e-3 * torch.rand_like(real)),
        "block_error": float((F.avg_pool2d(fake, block) - F.avg_pool2d(real, block)).abs().mean()),
        "block_error_black": float(F.avg_pool2d(real, block).abs().mean()),
    }


# The structure probes: the statistic each parameter moves, and the names of its range's two ends. Curly
# fur bends sideways and lies over the skin: over 16 held-out default-preset cameras (density and length
# mid-range, two strand instances) real coverage rose 0.23 -> 0.34 from curliness 0 to 1 (height where rays
# stop 0.07 -> 0.10, a smaller move).
PROBES = {
    "density": ("coverage", "sparse", "dense"),
    "length": ("height", "short", "long"),
    "curliness": ("coverage", "straight", "curly"),
}


def structure_response(model: MesoGAN, source: SlabSource, count: int) -> dict[str, float]:
    """How the generated pile follows its structure labels, against real strands under the same labels.
    Strand density is set to either end of its trained range (the other parameters at the middle of
    theirs) and the mean coverage of `count` held-out views is measured (the fraction of pixel-centre
    rays the pile stops); likewise strand length and the mean height where the rays stop (0 at the
    skin). The views keep their held-out cameras, lights and colours. Real figures are the first hits of
    those cameras on one strand instance grown with each end's parameters (no path tracing needed);
    generated ones come from renders of one latent and noise per view, so only the label differs
    between the two ends. Curliness is probed like density, by coverage."""
    c = model.config
    held_out = SlabSource(source.config, source.seed + HELD_OUT_SEED_OFFSET)
    instances = [held_out.draw(j) for j in range(count)]
    middle = {k: (lo + hi) / 2 for k, (lo, hi) in STRUCTURE_RANGES.items()}
    figures: dict[str, float] = {}
    for parameter, (statistic, low, high) in PROBES.items():
        lo, hi = STRUCTURE_RANGES[parameter]
        for end, value in ((low, lo), (high, hi)):
            structure = Structure(**(middle | {parameter: value}))
            tracer = instance_tracer(c, dataclasses.replace(instances[0], structure=structure))
            views = []
            for instance in instances:
                probe = dataclasses.replace(instance, structure=structure)
                blank = np.zeros((probe.camera.height, probe.camera.width, 3))
                views.append(View(probe, blank, first_hit_heights(tracer, probe.camera)))
            batch = stack_views(views, c.image_size)
            with torch.no_grad():
                torch.manual_seed(0)
                fake = fake_views(model, batch)
            coverage, height = view_structure(batch)
            real, generated = (
                (coverage, fake.opacity) if statistic == "coverage" else (height, fake.hit_height)
            )
            figures[f"{statistic}_{end}"] = float(generated.mean())
            figures[f"{statistic}_{end}_real"] = float(real.mean())
    return figures
