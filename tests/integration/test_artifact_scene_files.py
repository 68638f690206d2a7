"""A model of an uploaded scene is served without the job's folder: `prt` and `explore` artifacts of a
scene that reads a mesh, a glTF, a texture and an EXR sky are published to a real store with those files,
fetched by the inference service's loader (into a download folder it removes once the model is loaded)
and rendered.

The networks are untrained: what is tested is that every file a render reads travels with the artifact,
not the models' quality (`test_prt_job`, `test_explore_job`)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.loader import load_artifact
from tests.unit.test_portable_scene import KEPT, scene_with_files
from workers.models.explore import artifact as explore_artifact
from workers.models.explore.infer import ExploreRender
from workers.models.explore.network import PixelGenerator
from workers.models.prt import artifact
from workers.models.prt.infer import PrtRender
from workers.models.prt.network import PrtNetwork
from workers.models.registry import RENDER, get_kind
from workers.scene.format.spec import TranslateVariable
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.stored import CACHE_ENV


def served(tmp_path: Path, kind: str, files: dict, config, job: Path):
    """The artifact of `files` published to a store, the job's and the output folders removed, loaded."""
    store = ArtifactStore(BlobStore(str(tmp_path / "store")), str(tmp_path / "store"))
    manifest = store.publish(
        files, kind=kind, job_id=f"{kind}-0", scene_hash="sha256:" + "1" * 64,
        config=config.model_dump(mode="json"), code_version="test", metrics={},
    )  # fmt: skip
    assert {f"scene/{name}" for name in KEPT} <= {entry.name for entry in manifest.files}
    shutil.rmtree(job)
    shutil.rmtree(Path(files["scene.json"][0]).parent)
    work = tmp_path / "inference-work"
    loaded = load_artifact(store, manifest.artifact_id, "cpu", work)
    assert not any(work.iterdir())  # the download folder is gone; the scene's files are in the node's cache
    return loaded.model


def test_a_prt_artifact_of_an_uploaded_scene_relights_from_the_store_alone(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    job = tmp_path / "job"
    spec = scene_with_files(job)
    config = get_kind("prt").resolve_config("quick", {})
    box = compile_scene(spec, job).bounds
    files = artifact.save(tmp_path / "out", config, PrtNetwork(config), box, (0, 4), spec, job)
    model = served(tmp_path, "prt", files, config, job)
    params = PrtRender(camera={"width": 8, "height": 6}, lighting={"builtin": "forest"}, spp=1, wavelets=4)
    image = model.answer(RENDER, params, {}).arrays["image"]
    assert image.shape == (6, 8, 3) and np.isfinite(image).all() and image.mean() > 0


def test_an_explore_artifact_of_an_uploaded_scene_renders_its_variables_from_the_store_alone(
    tmp_path, monkeypatch
):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    job = tmp_path / "job"
    slide = TranslateVariable(name="slide", object="box", max=(0.4, 0.0, 0.0))
    spec = scene_with_files(job).model_copy(update={"variables": [slide]})
    config = get_kind("explore").resolve_config("quick", {})
    box = compile_scene(spec, job).bounds
    network = PixelGenerator.of(config, 1)
    files = explore_artifact.save(tmp_path / "out", config, network, spec, box, job)
    model = served(tmp_path, "explore", files, config, job)
    params = ExploreRender(camera={"width": 8, "height": 6}, values={"slide": [0.2, 0.0, 0.0]})
    image = model.answer(RENDER, params, {}).arrays["image"]
    assert image.shape == (6, 8, 3) and np.isfinite(image).all()
