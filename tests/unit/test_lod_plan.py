"""`lod` planning: which objects are prefiltered, which LoDs are built for given viewing distances, and
network sizes that match the networks actually built."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.models.lod.artifact import build_networks
from workers.models.lod.config import PRESETS, LodConfig
from workers.models.lod.grid import LodGrid
from workers.models.lod.plan import (
    choose_asset,
    choose_resolutions,
    cube_extent,
    octaves,
    parameter_count,
    plan,
)
from workers.models.registry import get_kind
from workers.scene.format.errors import SceneError
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef


def quick(**overrides) -> LodConfig:
    return get_kind("lod").resolve_config("quick", overrides)


def test_default_asset_skips_small_objects_and_emitters():
    scene = get_builtin("dense_foliage")
    asset = choose_asset(SceneRef(scene), quick())
    assert asset.names == ["branches", "leaves"]  # the 2-triangle ground stays on Embree
    ground = next(c for c in asset.choices if c.name == "ground")
    assert not ground.prefiltered and "triangles" in ground.reason
    assert asset.mesh_bytes > 0 and asset.triangles > 1000


def test_named_objects_and_unknown_names():
    scene = get_builtin("closed_box")
    assert choose_asset(SceneRef(scene), quick(objects=["box"])).names == [
        "box"
    ]  # 24 triangles, but asked for
    with pytest.raises(SceneError) as error:
        choose_asset(SceneRef(scene), quick(objects=["lid"]))
    assert error.value.field == "config.objects" and "'lid'" in str(error.value)


def test_nothing_to_prefilter_is_a_clear_error():
    with pytest.raises(SceneError, match="nothing to prefilter"):
        choose_asset(SceneRef(get_builtin("closed_box")), quick())  # the box is below min_triangles


def test_view_distances_pick_the_lod_whose_voxel_is_a_pixel():
    scene = get_builtin("menger_sponge")
    config = quick(finest_resolution=128, view_distances=[])
    extent = cube_extent(choose_asset(SceneRef(scene), config).bounds, 128)
    assert [r for r, _ in choose_resolutions(scene, config, extent)] == [128, 64, 32, 16, 8]
    camera = scene.camera
    pixel_at = lambda d: 2 * d * math.tan(math.radians(camera.fov) / 2) / camera.height  # noqa: E731
    # Distances at which a 32^3 and an 8^3 voxel cover exactly one pixel.
    near = extent / 32 / pixel_at(1.0)
    far = extent / 8 / pixel_at(1.0)
    config = quick(finest_resolution=128, view_distances=[near, far, far * 1.1])
    chosen = choose_resolutions(scene, config, extent)
    assert [r for r, _ in chosen] == [32, 8]
    assert "pixel" in chosen[0][1]
    # Much farther than the coarsest level serves: the coarsest; much nearer than LoD 0: LoD 0.
    config = quick(finest_resolution=128, view_distances=[far * 100, near / 100])
    assert [r for r, _ in choose_resolutions(scene, config, extent)] == [128, 8]


def test_plan_counts_parameters_like_the_built_networks():
    scene = get_builtin("menger_sponge")
    config = LodConfig.model_validate(PRESETS["quick"])
    triangles = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 1]]])
    grid = LodGrid.build(triangles, config.resolutions)
    networks = build_networks(config, grid)
    n_oct = octaves(grid.resolutions)
    sh = (config.sh_degree + 1) ** 2
    assert parameter_count(config.appearance, n_oct, 8, 2 * sh, 3) == sum(
        p.numel() for p in networks.appearance.parameters()
    )
    visibility = parameter_count(config.visibility, n_oct, 8, 0, 1, encoded_points=2)
    assert visibility == sum(p.numel() for p in networks.visibility.parameters())
    result = plan(SceneRef(scene), config)
    assert result.estimated_seconds > 0
    assert "32^3, 16^3, 8^3" in result.summary
    names = ["ground", "sponge", "LoD 0", "LoD 1", "LoD 2", "networks", "fixed costs"]
    assert [i.name for i in result.items] == names


def test_config_rejects_bad_resolutions():
    with pytest.raises(ValueError, match="power of two"):
        quick(finest_resolution=96)
    with pytest.raises(ValueError, match="must not exceed"):
        quick(finest_resolution=16, coarsest_resolution=32)
