"""The infinite plane generator (seamless windows, re-drawn and band-limited frequencies) and the decoder's
routing (appearance and light change radiance, never density; density ignores the camera)."""

from __future__ import annotations

import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.slab import SlabSamples, Window, query
from workers.models.mesogan.volume import mip_stack


def model() -> tuple[MesoganConfig, MesoGAN]:
    config = MesoganConfig.model_validate(PRESETS["quick"] | {"generator_layers": 3})
    torch.manual_seed(0)
    return config, MesoGAN(config).eval()


def test_windows_of_the_infinite_plane_agree_on_their_overlap_and_stitch_into_a_large_one():
    config, gan = model()
    w = gan.mapping(torch.randn(1, config.latent_dims), torch.rand(1, 3))
    noise = [gan.synthesis.draw_noise(torch.Generator().manual_seed(3))]
    with torch.no_grad():
        a = gan.synthesis(w, noise, (0, 0), (24, 24))
        b = gan.synthesis(w, noise, (12, -8), (24, 24))
        large = gan.synthesis(w, noise, (-40, -40), (48, 48))
        quarters = [
            gan.synthesis(w, noise, (-40 + 24 * i, -40 + 24 * j), (24, 24)) for i in (0, 1) for j in (0, 1)
        ]
    assert (a[..., 12:, :16] - b[..., :12, 8:]).abs().max() < 1e-5
    stitched = torch.cat([torch.cat(quarters[:2], -1), torch.cat(quarters[2:], -1)], -2)
    assert (large - stitched).abs().max() < 1e-5
    assert (a - b[..., :24, :24]).abs().max() > 1e-3  # different places differ


def test_frequencies_are_redrawn_and_each_layer_injects_its_own_band_below_nyquist():
    _, gan = model()
    first, second = gan.synthesis.draw_noise(), gan.synthesis.draw_noise()
    assert not torch.equal(first.input.frequencies, second.input.frequencies)
    cutoffs = gan.synthesis.cutoffs
    nyquist = 0.5 / gan.synthesis.texel
    assert torch.linalg.norm(first.input.frequencies, dim=-1).max() <= cutoffs[0]
    for layer, bank in enumerate(first.layers):
        magnitude = torch.linalg.norm(bank.frequencies, dim=-1)
        assert (magnitude > cutoffs[layer] - 1e-6).all() and (magnitude <= cutoffs[layer + 1] + 1e-6).all()
        assert (magnitude < nyquist).all()


def test_appearance_and_light_change_radiance_only_and_density_ignores_the_camera():
    config, gan = model()
    window = Window.centred(config.plane_resolution, config.texel)
    plane = gan.synthesis(
        gan.mapping(torch.randn(1, config.latent_dims), torch.rand(1, 3)),
        [gan.synthesis.draw_noise()],
        window.origin,
        window.size,
    )
    stack = mip_stack(plane, config.mip_levels)
    n = 64
    samples = SlabSamples(
        xy=torch.rand(1, n, 1, 2) * 4 - 2,
        height=torch.rand(1, n, 1),
        height_variance=torch.full((1, n, 1), 1e-3),
        radius=torch.full((1, n, 1), 0.3),
        deltas=torch.full((1, n, 1), 0.1),
    )
    with torch.no_grad():
        density, hidden = query(gan, config, stack, window, samples)
        again, _ = query(gan, config, stack, window, samples)
        light = torch.nn.functional.normalize(torch.rand(1, n, 1, 3) + torch.tensor([0, 0, 0.5]), dim=-1)
        view_a = torch.nn.functional.normalize(torch.rand(1, n, 1, 3), dim=-1)
        red, blue = torch.tensor([0.7, 0.1, 0.1]), torch.tensor([0.1, 0.1, 0.7])
        rho_red = gan.decoder.rho(hidden, red.expand(1, n, 1, 3), light, view_a)
        rho_blue = gan.decoder.rho(hidden, blue.expand(1, n, 1, 3), light, view_a)
        rho_other_light = gan.decoder.rho(hidden, red.expand(1, n, 1, 3), light.flip(-1), view_a)
        below = gan.decoder.rho(hidden, red.expand(1, n, 1, 3), light * torch.tensor([1, 1, -1]), view_a)
    assert torch.equal(density, again)  # no view, light or appearance input reaches density
    assert (rho_red - rho_blue).abs().max() > 1e-4 and (rho_red - rho_other_light).abs().max() > 1e-4
    assert torch.equal(below, torch.zeros_like(below))
