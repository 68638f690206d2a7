"""mesogan's plan and inference on an artifact (untrained weights: these check the plumbing, not quality):
the plan names the covered surfaces and refuses unknown ones, `generate` windows tile seamlessly,
`query` routes appearance to radiance only, `render` returns the requested frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.models.mesogan import KIND, artifact
from workers.models.mesogan.networks import MesoGAN
from workers.models.registry import get_inference
from workers.scene.builtin import get_builtin
from workers.scene.errors import SceneError
from workers.scene.reference import SceneRef


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
    plan = KIND.plan(scene, KIND.resolve_config("quick", {}))
    assert plan.items[0].choice == "fur" and "1280 triangles" in plan.items[0].reason
    assert plan.estimated_seconds > 0
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


def test_render_returns_the_requested_frame(loaded):
    inference, model = loaded
    params = inference.operations["render"].params(
        camera={"width": 12, "height": 8}, spp=1, background="neutral"
    )
    image = model.answer("render", params, {}).arrays["image"]
    assert image.shape == (8, 12, 3) and np.isfinite(image).all() and image.max() > 0
