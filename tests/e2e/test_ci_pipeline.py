"""The CI-pipeline scenario end to end: `ci_pipeline.sh` submits two scenes (a built-in one and an
uploaded folder) with `--wait --json` against a real `nbake serve`, downloads both artifacts, and fails
the build, with nbake's exit status, when a submission does not succeed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import NBAKE, TOKENS
from workers.scene.generators.builtin import get_builtin

served = grpc_server.served  # fixture
SCRIPT = Path(__file__).with_name("ci_pipeline.sh")
TINY = "--set width=32 --set height=32 --set spp=4"


def run_pipeline(served, out: Path, *scenes: str, submit_args: str = TINY) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")} | {
        "NBAKE_URL": served.url,
        "NBAKE_TOKEN": TOKENS["submit"],
        "NBAKE_CONFIG": str(out / "absent.toml"),
        "NBAKE": NBAKE,
        "NBAKE_SUBMIT_ARGS": submit_args,
        "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
    }
    return subprocess.run(
        ["bash", str(SCRIPT), str(out), *scenes], capture_output=True, text=True, env=env, timeout=600
    )


def test_two_scenes_are_built_and_downloaded(served, tmp_path):
    folder = tmp_path / "glossy"
    folder.mkdir()
    spec = get_builtin("cornell_glossy").model_dump(mode="json", exclude_none=True)
    (folder / "scene.yaml").write_text(yaml.safe_dump(spec))
    out = tmp_path / "build"
    done = run_pipeline(served, out, "cornell_box", str(folder))
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("ok: ") == 2
    for name in ("cornell_box", "glossy"):
        assert (out / name / "image.exr").stat().st_size > 0 and (out / name / "preview.png").is_file()
        assert not list((out / name).glob("*.part"))


def test_the_build_fails_when_a_submission_does_not_succeed(served, tmp_path):
    done = run_pipeline(served, tmp_path / "build", "cornell_box", submit_args=f"{TINY} --set spp=0")
    assert done.returncode == 2 and "FAILED: cornell_box" in done.stderr and "config.spp" in done.stderr
    assert not (tmp_path / "build" / "cornell_box").exists()
