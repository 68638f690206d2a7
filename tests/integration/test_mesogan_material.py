"""A scene file names a trained mesogan model as a material (`type: mesogan`): the path tracer draws its
shell over the surfaces using it, the `render` kind renders the scene end to end, in process and as a job
of the server with the artifact uploaded in the scene's folder, and the image is bit-identical to the
kind's own `:render` of the same scene, parameters and seed (one code path draws both). An unknown
artifact, a folder that holds none and misspelt parameters are refused naming the field; a scene whose
surfaces use no such material renders as it did without it, bit for bit.

A material may instead name the artifact by its id in the server's store (`artifact: sha256:...`): a
server job fetches it and renders the same image, bit for bit, as from the uploaded folder. An id that
does not exist, another tenant's artifact and an artifact of another kind are refused at submission (REST
and gRPC), naming the field and losing nothing stored; a render on this machine says it cannot fetch one.

The model is the `mesogan` kind's example job (the `quick` preset on `fur_ball`, as the kind contract
trains it), trained once for the module; the server's store holds it as an artifact placed there by hand
(the default tenant's), published twice under two ids."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import grpc
import numpy as np
import pytest
from google.protobuf import struct_pb2
from neuralbake.v1 import jobs_pb2, jobs_pb2_grpc

from services.api.grpc.server import start_grpc_server
from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.integration import test_api_server as api
from tests.integration.test_api_server import TOKENS, events, problem_of, submit, wait_for
from tests.integration.test_grpc_server import details, rpc_error
from tests.support.jobs import run_kind_job
from tests.support.ports import free_port
from workers.models.registry import get_inference, get_kind, register_materials
from workers.render import aggregate_materials
from workers.render.render import RenderSettings, render
from workers.scene.format.errors import SceneError
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import read_exr_channels
from workers.scene.portability.io import load_scene, scene_from_dict
from workers.scene.portability.reference import SceneRef

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
    (folder / name).write_text(json.dumps(scene_naming(material)))


OVERRIDES = {"width": SIZE, "height": SIZE, "spp": SPP, "tile_size": 64, "samplers": 0}
ARTIFACT_FIELD = "scene.materials.fur.artifact"


def scene_naming(material: dict) -> dict:
    """The test scene as `write_scene` writes it, as a dict (an inline scene of a job)."""
    data = get_builtin("fur_ball").model_dump(mode="json")
    data["materials"]["fur"] = {
        "type": "mesogan",
        "structure": STRUCTURE,
        "appearance": APPEARANCE,
        "seed": RENDER_SEED,
        "base": data["materials"]["fur"],
    } | material
    return data


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


def assert_same_render(a: np.ndarray, b: np.ndarray) -> None:
    """Renders from other processes agree to float rounding: torch's reductions follow the process's thread
    count (a Ray sampler actor runs one; the server's driver and the test process may run more)."""
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


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


def rendered(client, scene, folder: Path, samplers: int) -> tuple[dict, np.ndarray]:
    """A server render job of `scene` with the test's parameters, its tiles rendered in the driver or in
    `samplers` Ray sampler actors: the finished job and its image."""
    config = OVERRIDES | {"samplers": samplers}
    job = submit(client, kind="render", scene=scene, preset="quick", config=config, seed=RENDER_SEED)
    done = wait_for(client, job["id"], {"SUCCEEDED", "FAILED"})
    assert done["state"] == "SUCCEEDED", done
    logs = [e["data"].get("message", "") for e in events(client, job["id"]) if e["type"] == "log"]
    assert not samplers or any(f"on {samplers} sampler actor(s)" in message for message in logs), logs
    download = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "image.exr").write_bytes(download.content)
    (image,) = read_exr_channels(folder / "image.exr").values()
    return done, image


def upload(client, files: dict[str, bytes]) -> str:
    response = client.post("/v1/assets", files=[("files", (name, data)) for name, data in files.items()])
    assert response.status_code == 201, response.text
    return response.json()["asset_id"]


@pytest.fixture(scope="module")
def folder_route(trained, server, tmp_path_factory) -> tuple[dict, np.ndarray]:
    """The server job rendering the scene with the artifact uploaded in its folder (the tiles in a Ray
    sampler actor): the finished job and its image."""
    _, scene_dir = trained
    names = ["scene.json", *(f"models/fur/{f.name}" for f in (scene_dir / "models" / "fur").iterdir())]
    with server.client("admin") as client:
        asset = upload(client, {name: (scene_dir / name).read_bytes() for name in names})
        return rendered(client, asset, tmp_path_factory.mktemp("folder-route"), samplers=1)


def stored_artifact(folder: Path, store: str, job_id: str) -> str:
    """The artifact in `folder` placed in the store `store` by hand (as a job `job_id` would publish it),
    which makes it the default tenant's; its id."""
    files = {f.relative_to(folder).as_posix(): (str(f), "") for f in sorted(folder.rglob("*")) if f.is_file()}
    manifest = ArtifactStore(BlobStore(store), store).publish(
        files, kind="mesogan", job_id=job_id, scene_hash="", config={}, code_version="", metrics={}
    )
    return manifest.artifact_id


@pytest.fixture(scope="module")
def stored(trained, server) -> tuple[str, str]:
    """The trained artifact in the server's store, twice: two ids of the same files."""
    artifact, _ = trained
    return tuple(stored_artifact(artifact, server.settings.store, f"by-hand-{n}") for n in (1, 2))


def test_a_server_job_renders_the_material_from_the_uploaded_folder(trained, folder_route, client, tmp_path):
    artifact, scene_dir = trained
    _, image = folder_route
    assert_same_render(image, served_render(artifact))

    # A scene naming a folder the upload lacks is refused at upload, naming the field.
    (tmp_path / "scene.json").write_text((scene_dir / "scene.json").read_text().replace("models/fur", "fur"))
    refused = client.post(
        "/v1/assets", files=[("files", ("scene.json", (tmp_path / "scene.json").read_bytes()))]
    )
    assert refused.status_code == 422 and refused.json()["field"] == "materials.fur.path", refused.text


def test_a_server_job_renders_a_stored_artifact_named_by_id(stored, folder_route, server, client, tmp_path):
    artifact_id, same_files = stored
    _, by_folder = folder_route
    scene = scene_naming({"artifact": artifact_id})
    inline, image = rendered(client, scene, tmp_path / "inline", samplers=0)  # fetched by the driver
    assert_same_render(image, by_folder)
    asset = upload(client, {"scene.json": json.dumps(scene).encode()})  # the scene file alone
    uploaded, image = rendered(client, asset, tmp_path / "uploaded", samplers=1)  # and by a sampler actor
    assert_same_render(image, by_folder)
    assert uploaded["id"] != inline["id"]

    # The artifact id is part of the work's identity: the same id is the same job, another id another.
    request = {"kind": "render", "preset": "quick", "config": OVERRIDES, "seed": RENDER_SEED}
    assert submit(client, expect=200, scene=scene, **request)["id"] == inline["id"]
    other = submit(client, scene=scene_naming({"artifact": same_files}), **request)
    assert other["id"] != inline["id"] and other["scene_hash"] != inline["scene_hash"]
    client.post(f"/v1/jobs/{other['id']}:cancel")
    wait_for(client, other["id"], {"CANCELLED", "SUCCEEDED"})


def job_ids(client) -> list[str]:
    return [job["id"] for job in client.get("/v1/jobs", params={"limit": 200}).json()["items"]]


def test_an_artifact_the_caller_cannot_use_is_refused_naming_the_field(stored, folder_route, server, client):
    artifact_id, _ = stored
    render_artifact = folder_route[0]["artifact_id"]
    token = client.post("/v1/tokens", json={"tenant": "acme", "scope": "submit", "name": "test"}).json()
    acme, ours = (f"Bearer {secret}" for secret in (token["token"], TOKENS["submit"]))
    jobs_before = job_ids(client)
    unknown = "sha256:" + "0" * 64
    for artifact, caller, problem in (
        (unknown, ours, f"no artifact {unknown!r}"),
        (artifact_id, acme, f"no artifact {artifact_id!r}"),  # another tenant's: as if it did not exist
        (
            render_artifact,
            ours,
            f"{render_artifact} is a 'render' artifact: a mesogan material draws a 'mesogan' one",
        ),
    ):
        request = {"kind": "render", "scene": scene_naming({"artifact": artifact}), "preset": "quick"}
        body = problem_of(client.post("/v1/jobs", json=request, headers={"Authorization": caller}), 422)
        assert body["field"] == ARTIFACT_FIELD and body["detail"].startswith(problem), body
    # Nothing stored is lost: no job was made, and both artifacts are whole.
    assert job_ids(client) == jobs_before
    for artifact in (artifact_id, render_artifact):
        manifest = client.get(f"/v1/artifacts/{artifact}").json()
        assert all(
            client.get(f"/v1/artifacts/{artifact}/files/{f['name']}").status_code == 200
            for f in manifest["files"]
        )
    # gRPC submissions go through the same check.
    services = server.server.config.app.state.services
    spec_message = struct_pb2.Struct()
    spec_message.update(scene_naming({"artifact": unknown}))
    grpc_server = start_grpc_server(services, "127.0.0.1", free_port())
    try:
        with grpc.insecure_channel(f"127.0.0.1:{grpc_server.port}") as channel:
            request = jobs_pb2.SubmitJobRequest(kind="render", scene_spec=spec_message)
            metadata = (("authorization", f"Bearer {TOKENS['submit']}"),)
            error = rpc_error(
                jobs_pb2_grpc.JobServiceStub(channel).SubmitJob, request, metadata=metadata, timeout=60
            )
    finally:
        grpc_server.stop()
    assert error.code() == grpc.StatusCode.INVALID_ARGUMENT and details(error)["violation"] == ARTIFACT_FIELD


def test_a_material_names_its_artifact_once_and_a_local_render_cannot_fetch_one(stored, trained, client):
    artifact_id, _ = stored
    _, scene_dir = trained
    for material, problem in (
        ({"path": "models/fur", "artifact": artifact_id}, "give exactly one of `path`"),
        ({}, "give exactly one of `path`"),
        ({"artifact": "sha256:abc"}, "an artifact id is 'sha256:' and 64 hex digits"),
    ):
        response = client.post(
            "/v1/assets", files=[("files", ("scene.json", json.dumps(scene_naming(material))))]
        )
        body = problem_of(response, 422)
        assert body["field"] == "materials.fur.artifact" and body["detail"].startswith(problem), body

    # An upload with its own `.artifacts/` folder would mix with the artifacts a job puts there.
    asset = upload(
        client,
        {
            "scene.json": json.dumps(scene_naming({"artifact": artifact_id})).encode(),
            ".artifacts/x.txt": b"x",
        },
    )
    body = problem_of(
        client.post("/v1/jobs", json={"kind": "render", "scene": asset, "preset": "quick"}), 422
    )
    assert body["field"] == ARTIFACT_FIELD and ".artifacts/ folder" in body["detail"], body
    assert client.get(f"/v1/assets/{asset}").status_code == 200  # refused, not lost

    error = scene_error(scene_dir, {"artifact": artifact_id})
    assert error.field == "materials.fur.artifact" and f"nbake download {artifact_id}" in error.problem
