"""A scene file names a trained mesogan model as a material (`type: mesogan`): the path tracer draws its
shell over the surfaces using it, the `render` kind renders the scene end to end, in process and as a job
of the server with the artifact uploaded in the scene's folder, and the image is bit-identical to the
kind's own `:render` of the same scene, parameters and seed (one code path draws both). An unknown
artifact, a folder that holds none and misspelt parameters are refused naming the field; a scene whose
surfaces use no such material renders as it did without it, bit for bit.

The model is the `mesogan` kind's example job (the `quick` preset on `fur_ball`, as the kind contract
trains it)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from tests.integration import test_api_server as api
from tests.integration.test_api_server import events, submit, wait_for
from tests.support.jobs import run_kind_job
from workers.models.registry import get_inference, get_kind, register_materials
from workers.render import aggregate_materials
from workers.render.render import RenderSettings, render
from workers.scene.builtin import get_builtin
from workers.scene.compile import compile_scene
from workers.scene.errors import SceneError
from workers.scene.image_io import read_exr_channels
from workers.scene.io import load_scene, scene_from_dict
from workers.scene.reference import SceneRef

database, server, client = api.incidental_database, api.server, api.client  # fixtures
SEED = 5
STRUCTURE = {"length": 0.6, "density": 50.0, "curliness": 0.4}
APPEARANCE = {"hue": 0.6, "saturation": 0.7}
SIZE, SPP, RENDER_SEED = 24, 2, 3


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The folder of a scene file naming the example job's artifact, which lies beside it (`models/fur`)."""
    kind = get_kind("mesogan")
    folder = tmp_path_factory.mktemp("mesogan")
    _, outcome = run_kind_job(
        "mesogan", get_builtin(kind.example.scene), folder, kind.example.overrides, seed=SEED
    )
    assert outcome.state == "succeeded", outcome.error
    scene_dir = tmp_path_factory.mktemp("scene")
    shutil.copytree(folder / "out", scene_dir / "models" / "fur")
    write_scene(scene_dir, {"path": "models/fur"})
    return folder / "out", scene_dir


def write_scene(folder, material: dict, name: str = "scene.json") -> None:
    """fur_ball with its `fur` material a mesogan material over the same diffuse base, as a JSON file."""
    data = get_builtin("fur_ball").model_dump(mode="json")
    base = data["materials"]["fur"]
    data["materials"]["fur"] = {
        "type": "mesogan",
        "structure": STRUCTURE,
        "appearance": APPEARANCE,
        "seed": RENDER_SEED,
        "base": base,
    } | material
    (folder / name).write_text(json.dumps(data))


OVERRIDES = {"width": SIZE, "height": SIZE, "spp": SPP, "tile_size": 64, "samplers": 0}


def served_render(artifact) -> np.ndarray:
    """The kind's own `:render` of the artifact's scene with the test's parameters."""
    inference = get_inference("mesogan")
    model = inference.load(artifact, "cpu")
    params = inference.operations["render"].params(
        camera={"width": SIZE, "height": SIZE},
        spp=SPP,
        seed=RENDER_SEED,
        structure=STRUCTURE,
        appearance=APPEARANCE,
    )
    return model.answer("render", params, {}).arrays["image"]


def test_the_render_kind_draws_the_material_as_mesogan_render_does(trained, tmp_path):
    artifact, scene_dir = trained
    spec, base_dir = load_scene(scene_dir / "scene.json")
    kind = get_kind("render")
    plan = kind.plan(SceneRef(spec, base_dir), kind.resolve_config("quick", OVERRIDES))
    assert [i.choice for i in plan.items if i.name == "aggregate materials"] == ["fur (mesogan)"]
    _, outcome = run_kind_job("render", spec, tmp_path, OVERRIDES, seed=RENDER_SEED, scene_dir=base_dir)
    assert outcome.state == "succeeded", outcome.error
    (job_image,) = read_exr_channels(tmp_path / "out" / "image.exr").values()
    assert np.array_equal(job_image, served_render(artifact))

    # The shell is drawn: the bare ball (its base material) is another image, and so is another colour.
    settings = RenderSettings(spp=SPP, width=SIZE, height=SIZE, seed=RENDER_SEED)
    bare = render(compile_scene(get_builtin("fur_ball")), settings).image
    changed = np.abs(bare - job_image).max(axis=2) > 0.05
    assert 0.05 < changed.mean() < 0.9, changed.mean()
    write_scene(scene_dir, {"path": "models/fur", "appearance": {"hue": 0.3}}, "green.json")
    green = render(compile_scene(*load_scene(scene_dir / "green.json")), settings).image
    assert not np.allclose(green, job_image)


def scene_error(scene_dir, material: dict) -> SceneError:
    write_scene(scene_dir, material, "bad.json")
    register_materials()
    with pytest.raises(SceneError) as error:
        spec, base_dir = load_scene(scene_dir / "bad.json")
        render(compile_scene(spec, base_dir), RenderSettings(spp=1, width=4, height=4))
    return error.value


def test_an_unknown_artifact_or_bad_parameters_name_the_field(trained, tmp_path):
    _, scene_dir = trained
    missing = scene_error(scene_dir, {"path": "models/velvet"})
    assert missing.field == "materials.fur.path" and missing.problem.endswith("no such folder")
    (scene_dir / "empty").mkdir(exist_ok=True)
    empty = scene_error(scene_dir, {"path": "empty"})
    assert empty.field == "materials.fur.path" and "not a mesogan artifact" in empty.problem
    spec, base_dir = load_scene(scene_dir / "bad.json")
    _, outcome = run_kind_job("render", spec, tmp_path, OVERRIDES, scene_dir=base_dir)
    assert outcome.state == "failed" and "materials.fur.path" in outcome.error, outcome.error
    for material, field in (
        ({"path": "models/fur", "structure": {"lenght": 0.5}}, "materials.fur.structure.lenght"),
        ({"path": "models/fur", "apperance": {"hue": 0.5}}, "materials.fur.apperance"),
        ({"path": "models/fur", "seed": -1}, "materials.fur.seed"),
        ({"path": "models/fur", "shell_height": 0}, "materials.fur.shell_height"),
        (
            {"path": "models/fur", "base": {"type": "diffuse", "colour": [1, 0, 0]}},
            "materials.fur.base.colour",
        ),
        ({"path": ""}, "materials.fur.path"),
    ):
        assert scene_error(scene_dir, material).field == field, material


def test_an_unregistered_family_is_named(monkeypatch, trained):
    _, scene_dir = trained
    monkeypatch.setattr(aggregate_materials, "_families", {})
    error = scene_error(scene_dir, {"path": "models/fur"})
    assert error.field == "materials.fur.type" and "no renderer is registered for 'mesogan'" in error.problem


def test_a_scene_whose_surfaces_use_no_such_material_renders_as_without_it():
    plain = get_builtin("fur_ball")
    data = plain.model_dump(mode="json")
    data["materials"]["unused"] = {"type": "mesogan", "path": "no/such/folder"}  # never loaded
    settings = RenderSettings(spp=2, width=16, height=16, seed=1)
    with_unused = render(compile_scene(scene_from_dict(data)), settings).image
    assert np.array_equal(with_unused, render(compile_scene(plain), settings).image)


def test_a_server_job_renders_the_material_from_the_uploaded_folder(trained, client, tmp_path):
    artifact, scene_dir = trained
    names = ["scene.json", *(f"models/fur/{f.name}" for f in (scene_dir / "models" / "fur").iterdir())]
    files = [("files", (name, (scene_dir / name).read_bytes())) for name in names]
    response = client.post("/v1/assets", files=files)
    assert response.status_code == 201, response.text
    asset = response.json()["asset_id"]
    config = OVERRIDES | {"samplers": 1}  # the tiles are rendered in a Ray sampler actor
    job = submit(client, kind="render", scene=asset, preset="quick", config=config, seed=RENDER_SEED)
    done = wait_for(client, job["id"], {"SUCCEEDED", "FAILED"})
    assert done["state"] == "SUCCEEDED", done
    logs = [e["data"].get("message", "") for e in events(client, job["id"]) if e["type"] == "log"]
    assert any("on 1 sampler actor(s)" in message for message in logs), logs
    download = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr")
    (tmp_path / "image.exr").write_bytes(download.content)
    (image,) = read_exr_channels(tmp_path / "image.exr").values()
    assert np.array_equal(image, served_render(artifact))

    # A scene naming a folder the upload lacks is refused at upload, naming the field.
    (tmp_path / "scene.json").write_text((scene_dir / "scene.json").read_text().replace("models/fur", "fur"))
    refused = client.post(
        "/v1/assets", files=[("files", ("scene.json", (tmp_path / "scene.json").read_bytes()))]
    )
    assert refused.status_code == 422 and refused.json()["field"] == "materials.fur.path", refused.text
