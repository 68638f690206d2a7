"""`nbake bake` as a CI pipeline runs it, against a real `nbake serve`: six assets (built-in names and
uploaded folders with OBJ and glTF meshes) baked in one build; a deliberately broken gate fails the build
(exit 5, a JUnit failure, no lock written); the fixed gate passes (the jobs come back as identical work,
nothing trains again) and writes the lock; a third, unchanged run submits nothing. The command imports
no server code, as with the client-only install. The slow variant adds two trained kinds (lod, lsnif)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import pytest
import yaml

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import TOKENS
from tests.support.user_assets import user_folder
from workers.models.registry import get_kind
from workers.runtime.contract import merge_nested
from workers.scene.generators.builtin import get_builtin

served = grpc_server.served  # fixture
TINY_RENDER = {"width": 32, "height": 32, "spp": 4}
SHORT_TRAINING = {"train": {"steps": 8}, "evaluation_spp": 2, "reference_spp": 8}
BUILTIN = ["cornell_box", "cornell_glossy", "env_lit_objects"]
UPLOADED = ["cornell_box", "menger_sponge", "cornell_glossy"]  # each written as a user's folder

# Runs `nbake ARGS...` here and writes the imported module names to argv[1], to show which code it needed.
RUN_AND_LIST_MODULES = """
import atexit, json, sys
out, sys.argv = sys.argv[1], ["nbake", *sys.argv[2:]]
atexit.register(lambda: open(out, "w").write(json.dumps(sorted(sys.modules))))
from neuralbake_client.cli.main import app
app()
"""


def write_folder(root: Path, scene: str, name: str) -> None:
    for relative, data in user_folder(get_builtin(scene), name).items():
        (root / name / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / name / relative).write_bytes(data)


def pipeline(root: Path, gate: str, trained_kinds: bool) -> Path:
    """The pipeline file of the build, beside its asset folders."""
    for index, scene in enumerate(UPLOADED):
        if not (root / "assets" / f"user_{index}").exists():
            write_folder(root / "assets", scene, f"user_{index}")
    kinds = [{"kind": "render", "config": TINY_RENDER, "gates": [gate]}]
    assets: list = [*BUILTIN, "assets/user_*"]
    if trained_kinds:
        for name in ("lod", "lsnif"):
            example = get_kind(name).example
            folder = f"assets/example_{name}"
            if not (root / folder).exists():
                write_folder(root / "assets", example.scene, f"example_{name}")
            config = merge_nested(example.overrides, SHORT_TRAINING)
            kinds.append({"kind": name, "preset": "quick", "config": config, "gates": ["flip <= 1"]})
            assets.append({"scene": folder, "kinds": [name]})
        assets = [a if isinstance(a, dict) else {"scene": a, "kinds": ["render"]} for a in assets]
    document = {"concurrency": 8, "timeout": "20m", "assets": assets, "kinds": kinds}  # one batch
    path = root / "nbake.yaml"
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def bake(served, root: Path, *args: str) -> tuple[subprocess.CompletedProcess, set[str]]:
    listing = root / "modules.json"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")} | {
        "NBAKE_URL": served.url,
        "NBAKE_TOKEN": TOKENS["submit"],
        "NBAKE_CONFIG": str(root / "absent.toml"),
    }
    done = subprocess.run(
        [sys.executable, "-c", RUN_AND_LIST_MODULES, str(listing), "bake", "nbake.yaml", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=root,
        timeout=1500,
    )
    return done, set(json.loads(listing.read_text()))


def created(served) -> float:
    """How many submissions this server has answered with a new job."""
    return served.metric('nbake_job_submissions_total{created="true"}')


def check_build(served, root: Path, trained_kinds: bool) -> None:
    items = len(BUILTIN) + len(UPLOADED) + (2 if trained_kinds else 0)
    reports = ("--summary", "summary.json", "--junit", "junit.xml", "--json")

    pipeline(root, "spp >= 8", trained_kinds)  # the render config asks for 4 spp: this gate fails
    broken, modules = bake(served, root, *reports)
    assert broken.returncode == 5, broken.stdout + broken.stderr
    assert not {m.split(".")[0] for m in modules} & {"services", "workers", "torch", "ray"}
    summary = json.loads((root / "summary.json").read_text())
    assert summary["exit_status"] == 5 and len(summary["items"]) == items
    renders = [i for i in summary["items"] if i["kind"] == "render"]
    assert len(renders) == 6 and all(i["outcome"] == "gates_failed" for i in renders)
    assert all(i["outcome"] == "passed" for i in summary["items"] if i["kind"] != "render")
    assert all(i["submitted"] for i in summary["items"])
    suite = ElementTree.parse(root / "junit.xml").getroot()
    assert suite.get("tests") == str(items) and suite.get("failures") == "6" and suite.get("errors") == "0"
    failure = suite.find(".//testcase[@classname='assets/user_1']/failure")
    assert failure is not None and "spp >= 8" in failure.get("message")
    assert not (root / "nbake.lock.json").exists(), "a failed build wrote its lock"

    pipeline(root, "spp >= 4", trained_kinds)
    before = created(served)
    fixed, _ = bake(served, root, *reports)
    assert fixed.returncode == 0, fixed.stdout + fixed.stderr
    summary = json.loads((root / "summary.json").read_text())
    assert all(i["outcome"] == "passed" and i["reused"] for i in summary["items"])
    assert created(served) == before, "the fixed gate trained the same work again"
    lock = json.loads((root / "nbake.lock.json").read_text())
    assert len(lock["entries"]) == items

    again, _ = bake(served, root, "--json")
    assert again.returncode == 0, again.stdout + again.stderr
    build = json.loads(again.stdout.splitlines()[-1])
    assert build["event"] == "build" and build["submitted"] == 0 and build["passed"] == items
    assert created(served) == before


def test_a_build_fails_on_a_broken_gate_passes_when_fixed_and_reruns_without_submitting(served, tmp_path):
    check_build(served, tmp_path, trained_kinds=False)


@pytest.mark.slow
def test_a_build_of_three_kinds(served, tmp_path):
    check_build(served, tmp_path, trained_kinds=True)


REPO = Path(__file__).resolve().parents[2]
CI_EXAMPLES = {"github-actions.yml": "vendor.github-workflows", "gitlab-ci.yml": "vendor.gitlab-ci"}
CHECK_JSONSCHEMA = str(Path(sys.executable).with_name("check-jsonschema"))


def ci_commands(example: str) -> list[str]:
    """The `nbake` commands of a CI example: GitHub's steps' `run`, GitLab's jobs' `script` lines."""
    document = yaml.safe_load((REPO / "docs" / "ci" / example).read_text())
    if "jobs" in document:
        lines = [step["run"] for job in document["jobs"].values() for step in job["steps"] if "run" in step]
    else:
        lines = [line for job in document.values() if isinstance(job, dict) for line in job.get("script", [])]
    return [line for line in lines if line.startswith("nbake ")]


@pytest.mark.parametrize("example", CI_EXAMPLES)
def test_the_ci_examples_validate_against_their_systems_schemas(example, tmp_path):
    path = REPO / "docs" / "ci" / example
    check = [CHECK_JSONSCHEMA, "--builtin-schema", CI_EXAMPLES[example]]
    done = subprocess.run([*check, str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    broken = yaml.safe_load(path.read_text())
    job = broken["jobs"]["bake"] if "jobs" in broken else broken["bake"]
    job["timeout-minutes" if "jobs" in broken else "timeout"] = {"minutes": 60}  # a typo the schema catches
    (tmp_path / example).write_text(yaml.safe_dump(broken))
    assert subprocess.run([*check, str(tmp_path / example)], capture_output=True, timeout=120).returncode != 0


@pytest.mark.parametrize("example", CI_EXAMPLES)
def test_the_ci_examples_commands_bake_the_shipped_pipeline(example, served, tmp_path):
    (tmp_path / "scenes").symlink_to(REPO / "assets" / "scenes")  # the pipeline names ../scenes/example.yaml
    work = tmp_path / "repository"
    work.mkdir()
    (work / "nbake.yaml").write_text((REPO / "assets" / "pipelines" / "nbake.yaml").read_text())
    env = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")} | {
        "NBAKE_URL": served.url,
        "NBAKE_TOKEN": TOKENS["submit"],
        "NBAKE_CONFIG": str(tmp_path / "absent.toml"),
        "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
    }
    commands = ci_commands(example)
    assert commands, f"{example} runs no nbake command"
    for command in commands:
        done = subprocess.run(
            ["bash", "-c", command], cwd=work, env=env, capture_output=True, text=True, timeout=900
        )
        assert done.returncode == 0, f"{command}\n{done.stdout}{done.stderr}"
    assert ElementTree.parse(work / "nbake-junit.xml").getroot().get("failures") == "0"
    assert len(json.loads((work / "nbake.lock.json").read_text())["entries"]) == 2
