"""`lod` on a user's asset through the real server: a folder with a scene file and an OBJ mesh (a closed,
smooth, scan-like blob under a sun and a sky) is uploaded, planned on its real triangles, trained on a
sampler actor and published; the artifact is not flagged as worse than 1-spp path tracing."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import yaml

from services.jobs.scheduler import WARNING_ANNOTATION
from tests.integration.test_api_server import DatabaseChoice, ServerThread, events, settings_for, submit
from workers.scene.generators.builtin import get_builtin


def blob_obj() -> bytes:
    """A closed smooth mesh of 5120 triangles: an icosphere displaced by low-frequency bumps, with normals."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.45)
    v = sphere.vertices
    bumps = 1 + 0.12 * np.sin(3 * v[:, 0] + 1) * np.sin(4 * v[:, 1]) + 0.08 * np.cos(5 * v[:, 2])
    blob = trimesh.Trimesh(v * bumps[:, None], sphere.faces, process=False)
    return blob.export(file_type="obj", include_normals=True).encode()


def scene_yaml() -> bytes:
    """The Menger sponge's sun, sky, ground and camera, the sponge replaced by the uploaded blob."""
    scene = get_builtin("menger_sponge").model_dump(mode="json", exclude_none=True)
    scene["name"] = "scanned_blob"
    asset = next(o for o in scene["objects"] if o["name"] == "sponge")
    asset.update(name="blob", shape={"type": "mesh", "path": "meshes/blob.obj"})
    asset["transform"] = {"translate": [0.0, 0.5, 0.0]}
    return yaml.safe_dump(scene).encode()


@pytest.fixture(scope="module")
def client(ray_cluster, tmp_path_factory):
    with (
        ServerThread(
            settings_for(tmp_path_factory.mktemp("lod-asset"), DatabaseChoice("sqlite", None))
        ) as server,
        server.client("submit") as http,
    ):
        yield http


# slow: a trained model's quality check (77 s of the default suite on a 2-core machine); uploads through
# the server are tested by test_api_assets.py and lod's training and resume by test_lod_job.py
@pytest.mark.slow
def test_lod_trains_on_an_uploaded_mesh_through_the_server(client):
    files = [("scene.yaml", scene_yaml()), ("meshes/blob.obj", blob_obj())]
    response = client.post("/v1/assets", files=[("files", (name, data)) for name, data in files])
    assert response.status_code == 201, response.text
    asset_id = response.json()["asset_id"]

    job = submit(client, kind="lod", scene=asset_id, preset="quick", config={"samplers": 1})
    plan = {item["name"]: item for item in job["plan"]["items"]}
    assert plan["blob"]["choice"] == "prefilter" and "5120 triangles" in plan["blob"]["reason"]
    final = events(client, job["id"], timeout=600)[-1]["data"]
    assert final["state"] == "SUCCEEDED", final

    artifact_id = client.get(f"/v1/jobs/{job['id']}").json()["artifact_id"]
    manifest = client.get(f"/v1/artifacts/{artifact_id}").json()
    assert {"lod.json", "lod.safetensors", "report.json", "preview.png"} <= {
        f["name"] for f in manifest["files"]
    }
    assert WARNING_ANNOTATION not in manifest["annotations"], manifest["annotations"]
    assert manifest["metrics"]["worse_than_one_spp"] == 0.0
    assert all(np.isfinite(value) for value in manifest["metrics"].values())
