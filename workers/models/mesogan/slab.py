"""The generated material in an infinite slab: planes for a batch of labels and volume rendering of camera
rays through them (Sec. 6.2.6-6.2.7), what the discriminator compares with path-traced slab views.

A camera ray above the slab (height 1) is marched with `samples_per_ray` stratified samples down to the
base (height 0), where an opaque last sample stands for the skin. Each sample is a cone segment: its
Gaussian gives the variance of its height (the integrated encoding) and the radius of its footprint on
the plane (the mip level). Radiance is E rho(light) + A times a Monte Carlo estimate of rho's integral over
the hemisphere: rho per unit irradiance, the quantity the path tracer uses (`aggregate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.networks import MesoGAN, PlaneNoise
from workers.models.mesogan.volume import (
    HEIGHT_TO_RADIANS,
    composite,
    footprint_radius,
    mip_level,
    mip_stack,
    sample_mipmapped,
)

FIXED_NOISE_SEED = 0  # the `redraw_frequencies=False` ablation: StyleGAN3's frequencies, fixed once


@dataclass
class Window:
    """A window of the plane lattice: `origin` (texel index of its first texel) and `size` texels."""

    origin: tuple[int, int]
    size: tuple[int, int]
    texel: float

    @staticmethod
    def centred(resolution: int, texel: float) -> Window:
        return Window((-(resolution // 2), -(resolution // 2)), (resolution, resolution), texel)

    def uv(self, xy: Tensor) -> Tensor:
        """Plane positions (..., 2) to grid_sample coordinates in [0, 1]: (along axis 1, along axis 0)."""
        lo = torch.tensor(self.origin, dtype=xy.dtype, device=xy.device) * self.texel
        extent = torch.tensor(self.size, dtype=xy.dtype, device=xy.device) * self.texel
        uv = (xy - lo) / extent
        return uv.flip(-1)

    def widened(self, margin: int) -> Window:
        """This window with `margin` more texels of the lattice on every side."""
        origin = (self.origin[0] - margin, self.origin[1] - margin)
        return Window(origin, (self.size[0] + 2 * margin, self.size[1] + 2 * margin), self.texel)

    def bilinear(self, plane: Tensor, xy: Tensor) -> Tensor:
        """Features (N, C) of `plane` (C, H, W), this window's texels, at plane positions `xy` (N, 2),
        interpolated on the infinite plane's own lattice: the four texels and their weights follow from a
        position alone, never from the window, so every window holding them gives a point the same value
        (tiles agree with one large window up to their borders, where `grid_sample` would clamp).
        `ValueError` if a point's texels are not all in the window (widen it by one texel)."""
        lattice = xy.to(plane.device, torch.float64) / self.texel - 0.5  # texel centres at integers
        low = lattice.floor()
        weight = (lattice - low).to(plane.dtype)
        index = low.long() - torch.tensor(self.origin, device=plane.device)
        if ((index < 0) | (index + 1 >= torch.tensor(self.size, device=plane.device))).any():
            raise ValueError("points need the texels around them: widen the window by one texel")
        rows, cols = index[:, 0], index[:, 1]
        texels = lambda i, j: plane[:, rows + i, cols + j].T  # noqa: E731
        along = weight[:, :1]
        return (texels(0, 0) * (1 - along) + texels(1, 0) * along) * (1 - weight[:, 1:]) + (
            texels(0, 1) * (1 - along) + texels(1, 1) * along
        ) * weight[:, 1:]


def draw_noise(
    model: MesoGAN, config: MesoganConfig, count: int, seed: int | None = None
) -> list[PlaneNoise]:
    """The planes' random Fourier banks: from torch's stream in training (re-drawn every step), from `seed`
    at inference, and fixed for the ablation without re-drawing."""
    if not config.redraw_frequencies:
        seed = FIXED_NOISE_SEED
    generator = None if seed is None else torch.Generator().manual_seed(seed)
    return [model.synthesis.draw_noise(generator) for _ in range(count)]


def generate_planes(
    model: MesoGAN,
    config: MesoganConfig,
    structure: Tensor,
    latent: Tensor,
    noise: list[PlaneNoise],
    window: Window,
) -> Tensor:
    w = model.mapping(latent, structure)
    return model.synthesis(w, noise, window.origin, window.size)


@dataclass
class SlabSamples:
    """Samples along rays (B, N, S): plane positions, heights with their variance and footprint radius."""

    xy: Tensor
    height: Tensor
    height_variance: Tensor
    radius: Tensor
    deltas: Tensor


def march(
    origins: Tensor, directions: Tensor, pixel_radius: Tensor, samples: int, jitter: bool
) -> tuple[SlabSamples, SlabSamples]:
    """Stratified samples between the slab's top and its base and the base point itself (its own
    'samples' of size 1). Rays must point downwards (camera above the slab)."""
    dz = directions[..., 2].clamp(max=-1e-6)
    t_top = ((1.0 - origins[..., 2]) / dz).clamp(min=0.0)
    t_base = -origins[..., 2] / dz
    shape = (*origins.shape[:-1], samples)
    u = torch.rand(shape, device=origins.device) if jitter else torch.full(shape, 0.5, device=origins.device)
    step = ((t_base - t_top) / samples)[..., None]
    t = t_top[..., None] + (torch.arange(samples, device=origins.device) + u) * step
    cone = pixel_radius.reshape(-1, *([1] * (origins.dim() - 1)))

    def at(t: Tensor, axis_variance: Tensor) -> SlabSamples:
        p = origins[..., None, :] + t[..., None] * directions[..., None, :]
        radial = (t * cone) ** 2
        z2 = directions[..., None, 2] ** 2
        height_variance = axis_variance * z2 + radial * (1 - z2)
        radius = footprint_radius(axis_variance, radial, directions[..., None, 2])
        return SlabSamples(p[..., :2], p[..., 2], height_variance, radius, step.expand_as(t))

    inside = at(t, (step**2 / 12).expand_as(t))
    base = at(t_base[..., None], torch.zeros_like(t_base[..., None]))
    return inside, base


def query(
    model: MesoGAN, config: MesoganConfig, stack: list[Tensor], window: Window, s: SlabSamples
) -> tuple[Tensor, Tensor]:
    """Density (B, N, S) and the radiance head's hidden state at the samples."""
    b = s.xy.shape[0]
    uv = window.uv(s.xy).reshape(b, -1, 2)
    if config.mipmapping:
        level = mip_level(s.radius.reshape(b, -1), window.texel, len(stack))
    else:
        level = torch.zeros(uv.shape[:2], device=uv.device)
    features = sample_mipmapped(stack, uv, level).reshape(*s.height.shape, -1)
    return model.decoder.density(
        features, s.height * HEIGHT_TO_RADIANS, s.height_variance * HEIGHT_TO_RADIANS**2
    )


@dataclass
class SlabRender:
    """What the batch's cameras see of the generated slabs: HDR images (B, 3, H, W), and per pixel-centre
    ray (B, H * W) the opacity of the pile (1 - transmittance down to the skin) and the expected height
    at which the ray is stopped (0 at the skin): in expectation over instances, the fraction of real
    views' rays that hit a strand and the mean height of their first hits (`sampling.View`)."""

    image: Tensor
    opacity: Tensor
    hit_height: Tensor


def render_slab(
    model: MesoGAN,
    config: MesoganConfig,
    planes: Tensor,
    window: Window,
    batch: dict[str, Tensor],
    jitter: bool,
) -> SlabRender:
    """The batch's cameras looking at the generated slabs under its labels.

    Radiance at a sample is E rho(light) + A 2 pi mean_k rho(w_k) over `ambient_directions` uniform
    upper-hemisphere directions w_k: the same estimate of the incident integral the path tracer makes with
    its one traced direction (`aggregate`), so one rho serves both, unbiased."""
    stack = mip_stack(planes, config.mip_levels)
    inside, base = march(
        batch["origins"], batch["directions"], batch["pixel_radius"], config.samples_per_ray, jitter
    )
    density, hidden = query(model, config, stack, window, inside)
    _, base_hidden = query(model, config, stack, window, base)
    weights, remaining = composite(density, inside.deltas)
    hit_height = (weights * inside.height).sum(-1)
    opacity = 1.0 - remaining
    hidden = torch.cat([hidden, base_hidden], -2)
    weights = torch.cat([weights, remaining[..., None]], -1)
    view = -batch["directions"][..., None, :].expand(*hidden.shape[:-1], 3)
    light = batch["light"][:, None, None, :].expand_as(view)
    appearance = batch["appearance"][:, None, None, :].expand(*hidden.shape[:-1], -1)
    radiance = config.light_irradiance * model.decoder.rho(hidden, appearance, light, view)
    if config.ambient > 0:
        for _ in range(config.ambient_directions):
            direction = uniform_hemisphere(view.shape[:-1], view.device, jitter)
            rho = model.decoder.rho(hidden, appearance, direction, view)
            radiance = radiance + (config.ambient * 2 * math.pi / config.ambient_directions) * rho
    pixels = (weights[..., None] * radiance).sum(-2)  # (B, N, 3)
    size = math.isqrt(pixels.shape[1])
    image = pixels.permute(0, 2, 1).reshape(pixels.shape[0], 3, size, size)
    if "block" in batch:
        image = block_means(image, batch["block"])
    return SlabRender(image, opacity, hit_height)


def block_means(image: Tensor, block: Tensor) -> Tensor:
    """Each view's image (B, 3, H, W) as the means of its `block` (B,) pixel squares: a coarse view's
    pixel is one pixel-centre ray repeated, and the mean of its repeats' jittered estimates is its value
    (what the path-traced coarse view shows, `sampling.stack_views`)."""
    for k in block.unique().tolist():
        if k > 1:
            views = (block == k).nonzero()[:, 0]
            means = F.interpolate(F.avg_pool2d(image[views], int(k)), scale_factor=int(k), mode="nearest")
            image = image.index_put((views,), means)
    return image


def uniform_hemisphere(shape, device, random: bool) -> Tensor:
    """Uniform directions over the upper hemisphere (z up); without `random`, a fixed set (evaluation)."""
    if random:
        u = torch.rand(*shape, 2, device=device)
    else:
        generator = torch.Generator().manual_seed(FIXED_NOISE_SEED)
        u = torch.rand(*shape, 2, generator=generator).to(device)
    z, phi = u[..., 0], 2 * math.pi * u[..., 1]
    r = torch.sqrt((1 - z * z).clamp(min=0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
