"""The far-view figures measure what mipmapping is for: their truth is converged, far views pan by less
than a pixel (`evaluate.far_view_shimmer`), and a plane read through its mip levels shimmers less under
those pans than the same plane read at level 0 (point-sampled)."""

from __future__ import annotations

import numpy as np
import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.evaluate import (
    far_view_pans,
    generated_pans,
    held_out_ids,
    held_out_source,
    held_out_views,
    reference_spp,
    shimmer_figures,
)
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig, render_instance
from workers.models.mesogan.volume import tonemap
from workers.render.camera import PinholeCamera


def far_views(count: int):
    config = MesoganConfig.model_validate(PRESETS["default"])
    return config, far_view_pans(SlabSource(SlabSourceConfig(mesogan=config), 5), count)


def test_far_views_pan_by_less_than_a_pixel():
    """The first view's target seen from the last pan moves by about (PANS - 1) / PANS of a pixel where
    the camera looks straight down, less along the view's slope, never a whole pixel."""
    _, panned = far_views(4)
    for views in panned:
        first, last = views[0].camera, views[-1].camera
        pinhole = PinholeCamera(last)
        v = np.asarray(first.target) - pinhole.origin
        f = v @ pinhole.forward
        x = (v @ pinhole.right) / (f * (pinhole.right @ pinhole.right)) * last.width / 2
        y = (v @ pinhole.up) / (f * (pinhole.up @ pinhole.up)) * last.height / 2
        moved = float(np.hypot(x, y))
        assert 0.4 < moved < 1.0, moved


def test_a_plane_read_through_its_mip_levels_shimmers_less_than_at_level_0():
    """An untrained generator's plane has detail up to its texel's Nyquist: a far view's pixel (about
    three texels wide) that reads it at level 0 aliases (untrained default preset: shimmer 0.010 at level
    0 against 0.005 through the mip levels, path-traced strands 0.001)."""
    config, panned = far_views(6)
    torch.manual_seed(0)
    model = MesoGAN(config).eval()
    point_sampled = MesoGAN(config.model_copy(update={"mipmapping": False})).eval()
    point_sampled.load_state_dict(model.state_dict())
    filtered = shimmer_figures(generated_pans(model, panned))
    aliased = shimmer_figures(generated_pans(point_sampled, panned))
    assert filtered["shimmer"] < 0.7 * aliased["shimmer"], (filtered, aliased)


def test_a_held_out_far_views_pixels_are_converged():
    """A held-out coarse view's pixel stands for `coarse_block`^2 fine ones and is traced with as many
    times their samples (`reference_spp`): the truth of the far-view figures is the filtered radiance of
    the pixel's footprint, not Monte Carlo noise (at `training_spp` 0.03-0.06 over four default far views,
    where their pixels differ by 0.005-0.007)."""
    config = MesoganConfig.model_validate(PRESETS["default"])
    source = SlabSource(SlabSourceConfig(mesogan=config), 5)
    (j,) = held_out_ids(source, 1, coarse=True)
    instance = held_out_source(source).draw(j)
    block = config.image_size // instance.camera.width
    truth = held_out_views(source, 1, coarse=True)["image"][0, :, ::block, ::block]
    spp = 4 * reference_spp(config, instance.camera)
    converged = tonemap(torch.from_numpy(render_instance(config, instance, spp, seed=1).image)).permute(
        2, 0, 1
    )
    noise = float((truth - converged).pow(2).mean().sqrt())
    assert noise < 0.01, noise  # 0.022 with held-out views traced at training_spp
