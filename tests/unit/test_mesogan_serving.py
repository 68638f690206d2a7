"""mesogan's plan and inference on an artifact (untrained weights: these check the plumbing, not quality):
the plan names the covered surfaces and refuses unknown ones, `generate` windows tile seamlessly,
`query` routes appearance to radiance only and tiled queries agree with one large one between texels,
`render` returns the requested frame, of the scene asked for (kept, built-in or uploaded) with the shell
on the surfaces named."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from workers.models.mesogan import KIND, artifact
from workers.models.mesogan.infer import uploaded_mesh
from workers.models.mesogan.networks import MesoGAN
from workers.models.registry import get_inference
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Diffuse, SceneObject
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.portable import neutral_scene
from workers.scene.portability.reference import SceneRef


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    config = KIND.resolve_config("quick", {})
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("mesogan")
    artifact.save(folder, config, MesoGAN(config), get_builtin("fur_ball"))
    inference = get_inference("mesogan")
    return inference, inference.load(folder, "cpu")


def test_the_plan_names_the_surfaces_and_refuses_unknown_ones():
    scene = SceneRef(get_builtin("fur_ball"))
    config = KIND.resolve_config("quick", {})
    plan = KIND.plan(scene, config)
    surfaces, plane, networks, fixed = plan.items
    assert fixed.name == "fixed costs"
    assert surfaces.choice == "fur" and "1280 triangles" in surfaces.reason
    assert f"shell of height {config.shell_height:g}" in surfaces.reason
    # the ball's UV square spans 6.6 slab heights: 27 texels of 0.25, and training's mip depth
    assert plane.choice == f"27^2 x {config.plane_channels}, {config.mip_levels} mip levels"
    assert "closest view (2.63 away) reads level" in plane.reason
    assert networks.choice.startswith(
        f"generator {config.generator_layers}x{config.generator_width}, decoder"
    )
    assert plan.estimated_seconds > 0
    longer = KIND.plan(scene, KIND.resolve_config("quick", {"train": {"steps": 600}}))
    assert longer.estimated_seconds > 2 * plan.estimated_seconds
    with pytest.raises(SceneError) as error:
        KIND.plan(scene, KIND.resolve_config("quick", {"surfaces": ["velvet"]}))
    assert error.value.field == "config.surfaces"


def test_generated_windows_tile_and_queries_route_appearance_to_radiance(loaded):
    inference, model = loaded
    generate = inference.operations["generate"].params
    a = model.answer("generate", generate(origin=(0, 0), size=(20, 20), seed=4), {}).arrays["plane"]
    b = model.answer("generate", generate(origin=(10, 5), size=(20, 20), seed=4), {}).arrays["plane"]
    assert np.abs(a[10:, 5:] - b[:10, :15]).max() < 1e-5
    query = inference.operations["query"].params
    points = {"points": np.array([[0.1, 0.2, 0.5], [1.0, -1.0, 0.1]], np.float32)}
    red = model.answer("query", query(appearance={"hue": 0.0}), points).arrays
    green = model.answer("query", query(appearance={"hue": 0.33}), points).arrays
    assert np.array_equal(red["density"], green["density"]) and not np.allclose(red["rho"], green["rho"])
    with pytest.raises(ValueError, match=r"params\.size"):
        model.answer("generate", generate(size=(0, 4)), {})


def tiled_and_whole(model, query, points: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Density at `points` from the four windows of `half` texels around the origin, each point from the
    window of its quadrant, and from one window of 2 * `half` holding them all."""
    whole = model.answer("query", query(window=(-half, -half, 2 * half, 2 * half)), {"points": points})
    tiled = np.empty_like(whole.arrays["density"])
    for ox in (-half, 0):
        for oy in (-half, 0):
            mine = ((points[:, 0] >= 0) == (ox == 0)) & ((points[:, 1] >= 0) == (oy == 0))
            tile = model.answer("query", query(window=(ox, oy, half, half)), {"points": points[mine]})
            tiled[mine] = tile.arrays["density"]
    return tiled, whole.arrays["density"]


def test_tiled_queries_agree_with_one_large_query_between_texel_centres(loaded):
    inference, model = loaded
    query = inference.operations["query"].params
    texel = model.config.texel
    # Every 1/8 texel across both borders of four tiles, two texels either side of the corner they share,
    # and along each tile's outer edge (which a point may touch).
    across = np.arange(-16, 17) / 8 * texel
    x, y = np.meshgrid(across, across, indexing="ij")
    edge = np.full(9, 16 * texel)
    outer = np.stack([np.r_[x.ravel(), edge, -edge], np.r_[y.ravel(), across[::4], across[::4]]], -1)
    points = np.c_[outer, np.full(len(outer), 0.4)].astype(np.float32)
    tiled, whole = tiled_and_whole(model, query, points, 16)
    assert np.ptp(whole) > 0.05  # the density varies over these points
    np.testing.assert_allclose(tiled, whole, rtol=0, atol=1e-5 * np.ptp(whole))
    with pytest.raises(ValueError, match=r"^arrays\.points: points lie outside params\.window"):
        model.answer("query", query(window=(0, 0, 4, 4)), {"points": points})


def test_render_returns_the_requested_frame(loaded):
    inference, model = loaded
    params = inference.operations["render"].params(
        camera={"width": 12, "height": 8}, spp=1, background="neutral"
    )
    image = model.answer("render", params, {}).arrays["image"]
    assert image.shape == (8, 12, 3) and np.isfinite(image).all() and image.max() > 0


def render(model, inference, arrays=None, **params):
    params = inference.operations["render"].params(camera={"width": 8, "height": 8}, spp=1, **params)
    return model.answer("render", params, arrays or {})


def test_render_covers_the_named_surfaces_of_the_scene_asked_for(loaded):
    inference, model = loaded
    fur = render(model, inference)
    floor = render(model, inference, surfaces=["floor"])
    # the plane spans each covering's UV square at the trained texel size: the floor's is larger
    assert floor.meta["plane_resolution"] > fur.meta["plane_resolution"]
    assert not np.allclose(floor.arrays["image"], fur.arrays["image"])
    walls = render(model, inference, scene="cornell_box", surfaces=["red", "green"])
    assert walls.arrays["image"].shape == (8, 8, 3) and np.isfinite(walls.arrays["image"]).all()
    with pytest.raises(ValueError, match=r"^params\.surfaces: no material \['velvet'\]"):
        render(model, inference, surfaces=["fur", "velvet"])
    with pytest.raises(ValueError, match=r"^params\.scene: unknown built-in scene"):
        render(model, inference, scene="no_such_scene")


def square(size: float, uv_scale: float) -> np.ndarray:
    """Two triangles of a square in the y = 0 plane facing +y, UVs over [0, uv_scale]^2: (2, 3, 8)."""
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32)
    rows = [
        [size * x, 0.0, size * z, 0.0, 1.0, 0.0, uv_scale * (x + 1) / 2, uv_scale * (z + 1) / 2]
        for x, z in corners
    ]
    return np.array([[rows[0], rows[2], rows[1]], [rows[0], rows[3], rows[2]]], np.float32)


def test_render_covers_an_uploaded_mesh_with_its_uvs(loaded, tmp_path):
    inference, model = loaded
    mesh = square(1.0, 4.0)
    mesh[0, 0, 3:6] = (0.6, 0.8, 0.0)
    shape, _ = uploaded_mesh(mesh, tmp_path)
    scene = compile_scene(
        neutral_scene([SceneObject(name="m", shape=shape, material="m")], {"m": Diffuse()}), tmp_path
    )
    for compiled, uploaded in ((scene.positions, 0), (scene.shading_normals, 3), (scene.uvs, 6)):
        assert np.array_equal(compiled, mesh[..., uploaded : uploaded + compiled.shape[-1]])
    small = render(model, inference, {"mesh": square(1.0, 1.0)})
    large_uvs = render(model, inference, {"mesh": square(1.0, 4.0)})
    image = small.arrays["image"]
    assert np.isfinite(image).all() and image.max() > 0
    # the same world size over 4 times the UV span: the plane is laid over the UVs, at 1/4 the resolution
    assert large_uvs.meta["plane_resolution"] < small.meta["plane_resolution"]
    # Without UVs (all zero) the mesh is box-projected; the shell's height may follow the mesh's size.
    bare = render(model, inference, {"mesh": square(1.0, 0.0)}, shell_height_relative=0.05)
    assert np.isfinite(bare.arrays["image"]).all() and bare.arrays["image"].max() > 0
    with pytest.raises(ValidationError, match="at most one of `shell_height`"):
        render(model, inference, shell_height=0.1, shell_height_relative=0.05)
    with pytest.raises(ValueError, match=r"arrays\.mesh: expected"):
        render(model, inference, {"mesh": square(1.0, 1.0)[..., :5]})
    with pytest.raises(ValueError, match=r"params\.scene"):
        render(model, inference, {"mesh": square(1.0, 1.0)}, scene="cornell_box")
