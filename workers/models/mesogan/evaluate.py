"""Generation quality without a pretrained network: the sliced Wasserstein distance between Laplacian-
pyramid patches of generated and path-traced slab views (Karras et al. 2018's SWD, after Rabin et al.
2011), measured on held-out instances (their own seed stream) rendered under the same labels; and the
conditioning: how the coverage of generated views follows the strand density and curliness labels and the
height where their rays stop the strand length label, beside the same figures of real strands; and aliasing
at distance: how far views shimmer as the camera pans by fractions of a pixel, beside path-traced strands.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from workers.models.mesogan.config import STRUCTURE_RANGES, MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import (
    Instance,
    SlabSource,
    View,
    first_hit_heights,
    instance_tracer,
    render_instance,
    stack_views,
    to_scene,
)
from workers.models.mesogan.slab import Window, draw_noise, generate_planes, render_slab
from workers.models.mesogan.train import fake_views, view_structure
from workers.models.mesogan.volume import tonemap
from workers.render.render import RenderSettings, render
from workers.scene.format.spec import Camera, Structure

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


def held_out_source(source: SlabSource) -> SlabSource:
    return SlabSource(source.config, source.seed + HELD_OUT_SEED_OFFSET)


def held_out_ids(source: SlabSource, count: int, coarse: bool | None = None) -> list[int]:
    """The first `count` held-out instances, or only the coarse (or only the fine) views among them."""
    c = source.config.mesogan
    if coarse and not c.coarse_distances:
        raise ValueError("coarse views asked for, but the config has no coarse_distances")
    held_out = held_out_source(source)
    ids = (
        j
        for j in itertools.count()
        if coarse is None or (held_out.draw(j).camera.width < c.image_size) == coarse
    )
    return list(itertools.islice(ids, count))


def reference_spp(config: MesoganConfig, camera: Camera) -> int:
    """Samples per pixel of a held-out view: a coarse view's pixel stands for `coarse_block`^2 fine ones and
    takes as many times `training_spp`, so it shows the filtered radiance of its footprint that the mip
    levels stand for (Sec. 6.2.7). At `training_spp` alone, default-preset far views carried 0.03-0.06 of
    Monte Carlo noise (tonemapped RMS) where their pixels differ by 0.005-0.007: the far-view SWD of four
    default models (300 steps) was 0.232 / 0.238 / 0.241 / 0.245 against that truth and 0.200 / 0.199 /
    0.196 / 0.206 against this one, ranked otherwise. Training views keep `training_spp` (`config`)."""
    return config.training_spp * (config.image_size // camera.width) ** 2


def held_out_views(source: SlabSource, count: int, coarse: bool | None = None):
    """`count` path-traced instances no training batch draws (a seed of their own), as one batch; with
    `coarse`, only the coarse (or only the fine) views among them (`sampling`): the far views whose
    pixels read the coarse mip levels, where the thesis's no-mipmapping ablation aliases."""
    c = source.config.mesogan
    held_out = held_out_source(source)
    instances = {j: held_out.draw(j) for j in held_out_ids(source, count, coarse)}
    views = [render_instance(c, i, reference_spp(c, i.camera), seed=j) for j, i in instances.items()]
    return stack_views(views, c.image_size)


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


# The shimmer figure: each far view panned by k / PANS of its pixel's width, k < PANS, the truth of each pan
# path-traced at SHIMMER_SPP. Far views have 4^2 pixels at the default preset: 16 views cost about 30 CPU
# s, and the truth's Monte Carlo noise (0.004 tonemapped) sits below the shimmer of an untrained default
# model's renders (0.005 with mip levels, 0.010 reading level 0; path-traced strands 0.001).
PANS = 8
SHIMMER_SPP = 1024


def panned(instance: Instance, offset: float) -> Instance:
    """The instance with its camera (and its target) moved `offset` slab heights along the slab's x = y
    diagonal: the same view of another part of the infinite slab."""
    shift = to_scene(np.array([offset, offset, 0.0]) / np.sqrt(2.0))
    camera = instance.camera.model_copy(
        update={
            "position": tuple(np.add(instance.camera.position, shift)),
            "target": tuple(np.add(instance.camera.target, shift)),
        }
    )
    return dataclasses.replace(instance, camera=camera)


def pans(instance: Instance) -> list[Instance]:
    """The instance panned by k / PANS of its pixel's width at its target (normal to the view), k < PANS."""
    camera = instance.camera
    distance = float(np.linalg.norm(np.subtract(camera.position, camera.target)))
    pixel = 2 * distance * np.tan(np.radians(camera.fov) / 2) / camera.width
    return [panned(instance, pixel * k / PANS) for k in range(PANS)]


def far_view_pans(source: SlabSource, count: int) -> list[list[Instance]]:
    """`count` held-out far views, each as its PANS pans."""
    held_out = held_out_source(source)
    return [pans(held_out.draw(j)) for j in held_out_ids(source, count, coarse=True)]


def generated_pans(model: MesoGAN, panned: list[list[Instance]]) -> Tensor:
    """Tonemapped renders (views, PANS, 3, H, W) of one generated plane per view (under its structure
    labels) at every pan, without jitter: only the pan moves a pixel."""
    c = model.config
    window = Window.centred(c.plane_resolution, c.texel)
    side = panned[0][0].camera.width
    blank = np.zeros((side, side, 3)), np.zeros(side * side)
    structure = torch.from_numpy(np.stack([views[0].labels()["structure"] for views in panned])).float()
    with torch.no_grad():
        torch.manual_seed(0)
        latent = torch.randn(len(panned), c.latent_dims)
        planes = generate_planes(model, c, structure, latent, draw_noise(model, c, len(panned)), window)
        images = [
            render_slab(
                model, c, planes, window, stack_views([View(v[k], *blank) for v in panned], side), False
            )
            for k in range(len(panned[0]))
        ]
    return tonemap(torch.stack([i.image for i in images], 1))


def real_pans(config: MesoganConfig, panned: list[list[Instance]], spp: int) -> tuple[Tensor, float]:
    """Tonemapped path-traced renders (views, PANS, 3, H, W) of the strands at every pan (two more tiles
    around the slab, so no pan sees past it), and their Monte Carlo variance per pixel, from a second
    render of each first pan at another seed."""
    wider = config.model_copy(update={"tiles": min(config.tiles + 2, 9)})
    settings = RenderSettings(spp=spp, max_depth=config.max_depth, seed=0, threads=1)
    images, repeats = [], []
    for views in panned:
        tracer = instance_tracer(wider, views[0])
        images.append([render(tracer, settings, view=v.camera).image for v in views])
        again = settings.model_copy(update={"seed": 1})
        repeats.append(render(tracer, again, view=views[0].camera).image)
    to_tensor = lambda a: tonemap(torch.from_numpy(np.array(a, np.float32))).movedim(-1, -3)  # noqa: E731
    real, repeat = to_tensor(images), to_tensor(repeats)
    return real, float(0.5 * (real[:, 0] - repeat).pow(2).mean())


def shimmer_figures(images: Tensor, noise_variance: float = 0.0) -> dict[str, float]:
    """Of renders (views, PANS, 3, H, W): `shimmer`, the RMS over pixels of each pixel's standard deviation
    over the pans, and `contrast`, the RMS standard deviation over a view's pixels (first pan), each
    without `noise_variance`."""
    over_pans = images.var(1).mean() - noise_variance
    over_pixels = images[:, 0].flatten(2).var(-1).mean() - noise_variance
    return {
        "shimmer": float(over_pans.clamp(min=0).sqrt()),
        "contrast": float(over_pixels.clamp(min=0).sqrt()),
    }


def far_view_shimmer(
    model: MesoGAN, source: SlabSource, count: int, spp: int = SHIMMER_SPP
) -> dict[str, float]:
    """Aliasing at distance (Sec. 6.2.7, Fig. 6.5), which the pyramid SWD cannot see at far views (their
    4^2 pixels leave no Laplacian band, and each set's patches are normalised by their own spread, which
    divides out the excess contrast of point-sampled detail). Each of `count` held-out far views is panned
    by fractions of its pixel's width (`pans`) and measured by `shimmer_figures`: a pixel that filters its
    footprint barely moves under a sub-pixel pan, one that point-samples detail finer than the pixel
    jumps from sample to sample. Beside the same figures of the strands path-traced at `spp` (`_real`),
    their Monte Carlo noise taken out."""
    panned = far_view_pans(source, count)
    real, noise_variance = real_pans(model.config, panned, spp)
    generated = shimmer_figures(generated_pans(model, panned))
    truth = shimmer_figures(real, noise_variance)
    return generated | {f"{k}_real": v for k, v in truth.items()} | {"noise_real": noise_variance**0.5}
