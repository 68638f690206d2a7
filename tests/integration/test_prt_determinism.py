"""Same inputs, same model: a `prt` job trained on a quiet machine and the same job trained beside busy
loops in other processes store the same model. Every artifact file but the report's measurements (which
hold timings) is byte-identical, the served frame's spp is the same and so is the manifest's model digest.
`prt` is the kind whose artifact's frame used to be chosen by timing (`frame_spp`); the job lets it choose
(quick fixes the count)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.manifest import MEASUREMENT_FILES, MODEL_DIGEST
from services.artifacts.store import BlobStore
from tests.integration.test_inference_server import publish
from tests.support.jobs import run_kind_job
from workers.models.prt.artifact import load
from workers.scene.generators.builtin import get_builtin

SCENE = "env_lit_objects"
SEED = 3


@pytest.fixture
def cpu_hog():
    """Starts one busy loop a CPU in its own process on demand; teardown kills those still running."""
    started: list[subprocess.Popen] = []

    def start() -> list[subprocess.Popen]:
        for _ in range(os.cpu_count() or 1):
            started.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
        return started

    yield start
    for process in started:
        process.kill()
        process.wait(30)


def model_files(folder: Path) -> dict[str, str]:
    """sha256 of every file the job wrote but the report's measurements."""
    return {
        path.name: hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(folder.iterdir())
        if path.is_file() and path.name not in MEASUREMENT_FILES
    }


def test_a_job_beside_a_cpu_hog_stores_the_model_a_quiet_one_does(tmp_path, cpu_hog):
    store = ArtifactStore(BlobStore(str(tmp_path / "store")), str(tmp_path / "store"))
    runs = []
    for name in ("quiet", "loaded"):
        if name == "loaded":
            cpu_hog()
        spec, outcome = run_kind_job(
            "prt", get_builtin(SCENE), tmp_path / name, {"evaluation_spp": None}, seed=SEED
        )
        manifest = store.manifest(publish(store, "prt", spec, outcome).artifact_id)
        runs.append((Path(spec.output_dir), manifest))
    (quiet, quiet_manifest), (loaded, loaded_manifest) = runs
    assert load(quiet, "cpu").config.evaluation_spp == load(loaded, "cpu").config.evaluation_spp
    assert model_files(quiet) == model_files(loaded)
    assert quiet_manifest.annotations[MODEL_DIGEST] == loaded_manifest.annotations[MODEL_DIGEST]
    assert quiet_manifest.artifact_id != loaded_manifest.artifact_id  # the report's timings differ
