"""The structure a preset renders on the mesh lies where training draws its structure labels, and the
footprints (mip levels) it is read at lie where training draws its views."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.covering import covering
from workers.models.mesogan.plan import closest_view
from workers.models.mesogan.sampling import (
    View,
    draw_instance,
    normalized_structure,
    stack_views,
    to_local,
    widest_footprint,
)
from workers.models.mesogan.slab import march
from workers.models.mesogan.volume import mip_level
from workers.render.camera import PinholeCamera
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_presets_mesh_structure_is_inside_the_trained_labels(preset):
    config = MesoganConfig.model_validate(PRESETS[preset])
    on_mesh = normalized_structure(config.structure)
    rng = np.random.default_rng(0)
    drawn = np.stack([normalized_structure(draw_instance(config, rng).structure) for _ in range(256)])
    assert np.all((on_mesh >= 0.2) & (on_mesh <= 0.8)), on_mesh  # away from the ranges' sparse ends
    # training draws labels on both sides of it, near each: it is interpolated, never extrapolated
    assert np.all(drawn.min(0) < on_mesh - 0.1) and np.all(drawn.max(0) > on_mesh + 0.1)
    assert np.all(np.abs(drawn - on_mesh).min(0) < 0.02)


def test_the_default_preset_trains_the_mip_levels_its_mesh_reads():
    """Multi-scale training (Sec. 6.2.7) reads the plane's coarse mip levels, up to the level the default
    preset's fur ball is read at (its closest footprint, at the bench's 32^2): otherwise the decoder
    never learns what the mip stack's filtered features look like, and the shell reads them unlearnt.
    Only fine views (main's config before the coarse views) read level 0 alone: max level 0.0."""
    config = MesoganConfig.model_validate(PRESETS["default"])
    compiled = compile_scene(get_builtin("fur_ball"))
    camera = compiled.spec.camera.model_copy(update={"width": 32, "height": 32})
    compiled = dataclasses.replace(compiled, spec=compiled.spec.model_copy(update={"camera": camera}))
    cover = covering(compiled, config.surfaces, config.shell_height, config.texel)
    _, footprint = closest_view(compiled, cover.triangles, config.shell_height)
    mesh_level = math.log2(footprint / config.texel)
    rng = np.random.default_rng(0)
    views = []
    for _ in range(64):
        instance = draw_instance(config, rng)
        side = instance.camera.width
        views.append(View(instance, np.zeros((side, side, 3)), np.zeros(side * side)))
    batch = stack_views(views, config.image_size)
    inside, base = march(batch["origins"], batch["directions"], batch["pixel_radius"], 8, jitter=False)
    levels = mip_level(torch.cat([inside.radius.flatten(1), base.radius.flatten(1)], 1), config.texel, 3)
    assert mesh_level > 0.5, mesh_level  # the mesh reads above level 0...
    reading = (levels > 0.5).any(1).float().mean()
    assert reading > 0.2, reading  # ... and so do a good share of the training views,
    assert levels.max() >= mesh_level, (float(levels.max()), mesh_level)  # up to the mesh's level
    assert footprint < widest_footprint(config)  # so the shell's clamp leaves the closest pixels alone


def test_the_default_presets_views_stay_on_the_slab_and_the_generated_window():
    """Every training view's pixels, their whole area (the path tracer jitters within a pixel), meet the
    base inside the real slab (past it they see the sky, which an infinite generated slab cannot show)
    and inside the generated window (past it the plane is clamped to its border). A perspective image
    of the plane is the convex hull of its corners' hits. Main's coarse views (8^2 pixels from 12 slab
    heights at 60 degrees) reached 6.4 slab heights from the centre, past the slab's 5."""
    config = MesoganConfig.model_validate(PRESETS["default"])
    slab, window = config.tiles * config.tile / 2, config.plane_resolution * config.texel / 2
    rng = np.random.default_rng(0)
    reach = 0.0
    for _ in range(256):
        camera = draw_instance(config, rng).camera
        corners = np.array([0.0, camera.width])
        px, py = np.meshgrid(corners, corners)
        origins, directions = PinholeCamera(camera).rays(px.ravel(), py.ravel())
        origins, directions = to_local(origins), to_local(directions)
        assert np.all(directions[:, 2] < 0)
        hits = origins - (origins[:, 2] / directions[:, 2])[:, None] * directions
        reach = max(reach, float(np.abs(hits[:, :2]).max()))
    assert reach < min(slab, window), (reach, slab, window)
