"""What the training renderer reports of the generated pile beside its image (`SlabRender`): the opacity
of each pixel's ray down to the skin and the expected height where it stops, which the generator's
structure term matches to the real views' first hits. Checked on a slab of constant density, where both
are analytic."""

from __future__ import annotations

import math

import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.slab import Window, draw_noise, generate_planes, render_slab


def test_a_constant_density_slab_stops_vertical_rays_as_the_exponential_law_says():
    sigma = 2.0
    config = MesoganConfig.model_validate(PRESETS["quick"] | {"samples_per_ray": 64})
    torch.manual_seed(0)
    model = MesoGAN(config).eval()
    last = [m for m in model.decoder.trunk.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():  # density = softplus(out - 3) * 8 with out = 3 + log(expm1(sigma / 8))
        last.weight[0] = 0.0
        last.bias[0] = 3.0 + math.log(math.expm1(sigma / 8))
    xy = torch.tensor([[0.1, 0.2], [-0.3, 0.4], [0.5, -0.6], [0.0, 0.0]])
    batch = {
        "origins": torch.cat([xy, torch.full((4, 1), 2.0)], -1)[None],
        "directions": torch.tensor([0.0, 0.0, -1.0]).expand(1, 4, 3),
        "pixel_radius": torch.tensor([1e-3]),
        "light": torch.tensor([[0.0, 0.6, 0.8]]),
        "appearance": torch.tensor([[0.5, 0.4, 0.3]]),
    }
    window = Window.centred(config.plane_resolution, config.texel)
    with torch.no_grad():
        planes = generate_planes(
            model, config, torch.full((1, 3), 0.5), torch.randn(1, config.latent_dims),
            draw_noise(model, config, 1, 0), window,
        )  # fmt: skip
        rendered = render_slab(model, config, planes, window, batch, jitter=False)
    opacity = 1 - math.exp(-sigma)
    # E[z; stopped] for a ray entering at z = 1: the integral of sigma exp(-sigma t) (1 - t) over t in [0, 1]
    height = opacity - (1 - math.exp(-sigma) * (1 + sigma)) / sigma
    assert torch.allclose(rendered.opacity, torch.tensor(opacity), rtol=1e-4), rendered.opacity
    assert torch.allclose(rendered.hit_height, torch.tensor(height), rtol=1e-3), rendered.hit_height
