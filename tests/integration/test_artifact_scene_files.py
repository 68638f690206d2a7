"""A model of an uploaded scene is served without the job's folder: a `prt` artifact of a scene that reads
a mesh, a glTF, a texture and an EXR sky is published to a real store with those files, fetched by the
inference service's loader (into a download folder it removes once the model is loaded) and relit.

The network is untrained: what is tested is that every file the relighting reads travels with the
artifact, not the model's quality (`test_prt_job`)."""

from __future__ import annotations

import shutil

import numpy as np

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.loader import load_artifact
from tests.unit.test_portable_scene import KEPT, scene_with_files
from workers.models.prt import artifact
from workers.models.prt.infer import PrtRender
from workers.models.prt.network import PrtNetwork
from workers.models.registry import RENDER, get_kind
from workers.scene.compile import compile_scene
from workers.scene.stored import CACHE_ENV


def test_a_prt_artifact_of_an_uploaded_scene_relights_from_the_store_alone(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    job, out, work = tmp_path / "job", tmp_path / "out", tmp_path / "inference-work"
    spec = scene_with_files(job)
    config = get_kind("prt").resolve_config("quick", {})
    box = compile_scene(spec, job).bounds
    files = artifact.save(out, config, PrtNetwork(config), box, (0, 4), spec, job)
    store = ArtifactStore(BlobStore(str(tmp_path / "store")), str(tmp_path / "store"))
    manifest = store.publish(
        files, kind="prt", job_id="prt-0", scene_hash="sha256:" + "1" * 64,
        config=config.model_dump(mode="json"), code_version="test", metrics={},
    )  # fmt: skip
    assert {f"scene/{name}" for name in KEPT} <= {entry.name for entry in manifest.files}
    shutil.rmtree(job)
    shutil.rmtree(out)

    loaded = load_artifact(store, manifest.artifact_id, "cpu", work)
    assert not any(work.iterdir())  # the download folder is gone; the scene's files are in the node's cache
    params = PrtRender(camera={"width": 8, "height": 6}, lighting={"builtin": "forest"}, spp=1, wavelets=4)
    image = loaded.model.answer(RENDER, params, {}).arrays["image"]
    assert image.shape == (6, 8, 3) and np.isfinite(image).all() and image.mean() > 0
