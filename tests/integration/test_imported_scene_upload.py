"""glTF and USD scenes through the real server and CLI: a `.glb` uploaded on its own renders as a job (its
notes in the plan) to the image a direct render of the file gives; a `.gltf` with its buffer and images,
and a YAML scene importing a `.glb`, are assets; broken uploads are 4xx naming the glTF field."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from neuralbake_client.cli.main import app
from typer.testing import CliRunner

from tests.integration.test_api_server import (
    DatabaseChoice,
    ServerThread,
    events,
    problem_of,
    settings_for,
    submit,
)
from tests.support.gltf_files import GltfBuilder, quad
from workers.models.render.config import RenderConfig
from workers.render.render import render
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import read_exr
from workers.scene.portability.io import load_scene

SEED = 3


def textured_scene(external_image: bool) -> GltfBuilder:
    """A textured, normal-mapped, rough-metal quad floor and an emissive quad over it, instanced twice;
    no camera and no punctual light (the importer adds a camera; the emitters light it)."""
    builder = GltfBuilder()
    rng = np.random.default_rng(0)
    base = builder.texture(
        builder.image(rng.integers(0, 256, (8, 8, 3)), uri="tex/base.png" if external_image else None)
    )
    bumps = builder.texture(builder.image(np.full((2, 2, 3), (150, 128, 240))))
    floor = builder.material(
        name="Floor",
        pbrMetallicRoughness={
            "baseColorTexture": {"index": base},
            "metallicFactor": 0.3,
            "roughnessFactor": 0.6,
        },
        normalTexture={"index": bumps},
    )
    lamp = builder.material(
        name="Lamp", emissiveFactor=[4.0, 4.0, 3.0], pbrMetallicRoughness={"metallicFactor": 0.0}
    )
    builder.node(
        mesh=quad(builder, floor, name="floor"), rotation=[-0.7071068, 0, 0, 0.7071068], scale=[3, 3, 3]
    )
    lamp_mesh = quad(builder, lamp, name="lamp")
    for x in (-1.0, 1.0):
        builder.node(
            mesh=lamp_mesh, translation=[x, 2.0, 0.0], rotation=[0.7071068, 0, 0, 0.7071068], scale=[0.4] * 3
        )
    return builder


@pytest.fixture(scope="module")
def client(ray_cluster, tmp_path_factory):
    with (
        ServerThread(settings_for(tmp_path_factory.mktemp("gltf"), DatabaseChoice("sqlite", None))) as server,
        server.client("submit") as http,
    ):
        yield http


def upload(client, files: list[tuple[str, bytes]]):
    return client.post("/v1/assets", files=[("files", (name, data)) for name, data in files])


@pytest.mark.slow
def test_a_glb_uploaded_alone_renders_as_a_job_like_a_direct_render(client, tmp_path):
    path = textured_scene(external_image=False).save(tmp_path / "model.glb")
    response = upload(client, [("model.glb", path.read_bytes())])
    assert response.status_code == 201, response.text
    asset = response.json()
    assert asset["scene_file"] == "model.glb"

    job = submit(
        client,
        kind="render",
        scene=asset["asset_id"],
        preset="quick",
        seed=SEED,
        config={"spp": 4, "samplers": 0},
    )
    notes = [item["choice"] for item in job["plan"]["items"] if item["name"] == "scene import"]
    assert any(n.startswith("camera:") for n in notes)  # the file has no camera: the plan says so
    assert events(client, job["id"])[-1]["data"]["state"] == "SUCCEEDED"
    done = client.get(f"/v1/jobs/{job['id']}").json()
    image = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr")
    (tmp_path / "service.exr").write_bytes(image.content)

    scene, folder = load_scene(path)
    direct = render(compile_scene(scene, folder), RenderConfig.model_validate(done["config"]).settings(SEED))
    served = read_exr(tmp_path / "service.exr")
    np.testing.assert_array_equal(served, direct.image)
    assert served.mean() > 1e-3 and (served > 0.02).any()  # lit by the emissive lamps


def test_a_glb_uploaded_alone_is_an_asset_whose_scene_is_the_import(client, tmp_path):
    path = textured_scene(external_image=False).save(tmp_path / "model.glb")
    response = upload(client, [("model.glb", path.read_bytes())])
    assert response.status_code == 201, response.text
    assert response.json()["scene_file"] == "model.glb"
    assert {f["name"] for f in response.json()["files"]} == {"model.glb"}


def test_a_gltf_with_its_files_and_a_yaml_importing_a_glb_are_assets(client, tmp_path):
    path = textured_scene(external_image=True).save(tmp_path / "loose" / "model.gltf")
    files = [
        (p.relative_to(path.parent).as_posix(), p.read_bytes()) for p in path.parent.rglob("*") if p.is_file()
    ]
    assert {name for name, _ in files} == {"model.gltf", "model.bin", "tex/base.png"}
    assert upload(client, files).status_code == 201

    glb = textured_scene(external_image=False).save(tmp_path / "model.glb").read_bytes()
    scene = {"import": "assets/model.glb", "camera": {"position": [0, 3, 6], "target": [0, 0, 0]}}
    response = upload(client, [("scene.yaml", yaml.safe_dump(scene).encode()), ("assets/model.glb", glb)])
    assert response.status_code == 201, response.text
    assert response.json()["scene_file"] == "scene.yaml"


def test_broken_gltf_uploads_are_4xx_naming_the_field(client, tmp_path):
    path = textured_scene(external_image=True).save(tmp_path / "model.gltf")
    body = problem_of(upload(client, [("model.gltf", path.read_bytes()), ("tex/base.png", b"x")]), 422)
    assert "buffers[0].uri" in body["field"]  # the .bin was not sent
    escaping = path.read_text().replace('"tex/base.png"', '"../base.png"')
    files = [("model.gltf", escaping.encode()), ("model.bin", (tmp_path / "model.bin").read_bytes())]
    body = problem_of(upload(client, files), 422)
    assert "outside" in body["detail"] and "baseColorTexture" in body["field"]


def test_nbake_render_takes_a_glb(tmp_path):
    path = textured_scene(external_image=False).save(tmp_path / "model.glb")
    result = CliRunner().invoke(
        app,
        [
            "render",
            str(path),
            "-o",
            str(tmp_path / "out.exr"),
            "--width",
            "24",
            "--height",
            "24",
            "--spp",
            "2",
        ],
    )
    assert result.exit_code == 0, result.stderr
    assert "camera: none in the file" in result.stderr
    assert read_exr(tmp_path / "out.exr").shape == (24, 24, 3)


def test_usdz_and_usda_uploads(client, tmp_path):
    pytest.importorskip("pxr")
    from pxr import Sdf, UsdUtils

    from tests.unit.test_scene_usd import write_usd

    source = write_usd(tmp_path / "src", ".usdc")
    UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(source)), str(tmp_path / "scene.usdz"))
    response = upload(client, [("scene.usdz", (tmp_path / "scene.usdz").read_bytes())])
    assert response.status_code == 201, response.text
    assert response.json()["scene_file"] == "scene.usdz"

    text = '#usda 1.0\ndef "World" {\n    def "Ref" (prepend references = @../elsewhere.usda@) {}\n}\n'
    body = problem_of(upload(client, [("scene.usda", text.encode())]), 422)
    assert body["field"] == "scene.usda: /World/Ref" and "elsewhere.usda" in body["detail"]


@pytest.mark.slow
def test_lod_trains_on_an_uploaded_glb(client, tmp_path):
    """`nbake submit model.gltf --kind lod`: the file and its buffer and texture are the scene the model
    trains on (two textured spheres, a textured floor, an emissive panel, a point light and a camera)."""
    from tests.unit.test_scene_usd import write_gltf

    path = write_gltf(tmp_path / "gltf")
    files = [(p.name, p.read_bytes()) for p in path.parent.iterdir()]
    asset = upload(client, files).json()
    job = submit(client, kind="lod", scene=asset["asset_id"], preset="quick", config={"samplers": 1})
    plan = {item["name"]: item["choice"] for item in job["plan"]["items"]}
    assert plan["gold"] == plan["blend"] == "prefilter"  # the imported spheres are what lod models
    final = events(client, job["id"], timeout=900)[-1]["data"]
    assert final["state"] == "SUCCEEDED", final
