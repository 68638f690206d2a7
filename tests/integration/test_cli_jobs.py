"""`nbake submit | jobs | show | watch | cancel | download` as a CI pipeline runs them: subprocesses
without a terminal (so JSON lines), against a real `nbake serve`, checking every exit status."""

from __future__ import annotations

import json
import os
import socket
import subprocess
from pathlib import Path

import pytest
from neuralbake_client import Client

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import NBAKE, TOKENS
from tests.integration.test_grpc_server import TINY
from workers.scene.generators.builtin import get_builtin

served = grpc_server.served  # fixture
TINY_SETS = ["--set", "width=32", "--set", "height=32", "--set", "spp=4"]


def nbake(*args: str, env: dict | None = None, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([NBAKE, *args], capture_output=True, text=True, timeout=timeout, env=env)


def lines(stdout: str) -> list[dict]:
    """Every stdout line is one JSON object, with no terminal escape codes."""
    assert "\x1b" not in stdout
    return [json.loads(line) for line in stdout.splitlines()]


@pytest.fixture(params=["rest", "grpc"])
def env(request, served, tmp_path) -> dict:
    url = served.url if request.param == "rest" else served.grpc_url
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")}
    return clean | {
        "NBAKE_URL": url,
        "NBAKE_TOKEN": TOKENS["admin"],
        "NBAKE_CONFIG": str(tmp_path / "none.toml"),
    }


def dark_scene() -> dict:
    """Valid at submission, but it has no light, so the render fails when it runs (uploads refuse it)."""
    spec = get_builtin("cornell_box").model_dump(mode="json", exclude_none=True)
    spec["objects"] = [o for o in spec["objects"] if not o.get("emission")]
    return spec


def test_submit_wait_json_succeeds_and_download_gets_the_files(env, tmp_path):
    done = nbake(
        "submit", "cornell_box", "--kind", "render", "--preset", "quick", *TINY_SETS, "--wait", env=env
    )
    assert done.returncode == 0, done.stderr
    events = lines(done.stdout)
    assert events[0]["event"] == "submitted" and events[-1]["event"] == "result"
    job = events[-1]["job"]
    assert job["state"] == "SUCCEEDED" and job["config"]["spp"] == 4
    assert all(e["job_id"] == job["id"] for e in events[1:-1])
    again = lines(
        nbake("submit", "cornell_box", "--kind", "render", "--preset", "quick", *TINY_SETS, env=env).stdout
    )
    assert again[0]["event"] == "submitted" and again[0]["reused"] and again[0]["job"]["id"] == job["id"]

    shown = nbake("show", job["id"], "--json", env=env)
    assert shown.returncode == 0 and lines(shown.stdout)[0]["job"]["artifact_id"] == job["artifact_id"]
    by_digest = nbake("show", job["artifact_id"].removeprefix("sha256:"), env=env)  # the job that made it
    assert by_digest.returncode == 0, by_digest.stderr
    assert lines(by_digest.stdout)[0]["job"]["id"] == job["id"]
    listed = lines(nbake("jobs", "--state", "SUCCEEDED", "--kind", "render", env=env).stdout)
    assert job["id"] in {line["job"]["id"] for line in listed}

    fetched = nbake("download", job["id"], "-o", str(tmp_path / "out"), env=env)
    assert fetched.returncode == 0, fetched.stderr
    files = {line["name"]: line for line in lines(fetched.stdout)}
    assert {"image.exr", "preview.png"} <= set(files)
    assert Path(files["image.exr"]["path"]).stat().st_size == files["image.exr"]["size"]

    # an interrupted download: the partial file is resumed, not fetched again
    image = Path(files["image.exr"]["path"])
    data = image.read_bytes()
    image.unlink()
    image.with_name("image.exr.part").write_bytes(data[:1000])
    again = nbake("download", job["artifact_id"], "-o", str(tmp_path / "out"), "--name", "image.exr", env=env)
    (line,) = lines(again.stdout)
    assert again.returncode == 0 and line["resumed_from"] == 1000 and image.read_bytes() == data


def test_a_failed_job_exits_1(env):
    with Client(env["NBAKE_URL"], env["NBAKE_TOKEN"]) as sdk:
        job = sdk.submit("render", dark_scene(), preset="quick", config=TINY, force=True)
    done = nbake("watch", job.id, env=env)
    assert done.returncode == 1, done.stderr
    result = lines(done.stdout)[-1]
    assert result["job"]["state"] == "FAILED" and "light" in result["job"]["error"]


def test_a_cancelled_job_exits_3(env):
    long = ["--set", "spp=65536", "--set", "width=32", "--set", "height=32", "--force"]
    submitted = nbake("submit", "cornell_box", "--kind", "render", "--preset", "quick", *long, env=env)
    job_id = lines(submitted.stdout)[0]["job"]["id"]
    watcher = subprocess.Popen([NBAKE, "watch", job_id], stdout=subprocess.PIPE, text=True, env=env)
    try:
        for raw in watcher.stdout:
            if json.loads(raw)["event"] == "progress":
                break
        cancelled = nbake("cancel", job_id, env=env)
        assert cancelled.returncode == 0 and lines(cancelled.stdout)[0]["job"]["cancel_requested"]
        rest = watcher.stdout.read()
        assert watcher.wait(120) == 3
        assert lines(rest)[-1]["job"]["state"] == "CANCELLED"
    finally:
        if watcher.poll() is None:
            watcher.kill()
            watcher.wait()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["submit", "cornell_box", "--kind", "render", "--set", "spp=0"], "config.spp"),
        (["submit", "cornell_box", "--kind", "nope"], "kind"),
        (["submit", "cornell_box", "--kind", "render", "--set", "spp"], "--set"),
        (["submit", "cornell_box"], "--kind"),
        (["show", "job-missing"], "no job"),
    ],
)
def test_usage_and_validation_errors_exit_2(env, args, message):
    done = nbake(*args, env=env)
    assert done.returncode == 2 and message in done.stderr, done.stderr


def test_unreachable_server_or_bad_token_exits_4(env):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    scheme = env["NBAKE_URL"].split(":", 1)[0]
    unreachable = nbake("jobs", env=env | {"NBAKE_URL": f"{scheme}://127.0.0.1:{port}"})
    assert unreachable.returncode == 4 and "error:" in unreachable.stderr
    stranger = nbake("jobs", env=env | {"NBAKE_TOKEN": "wrong"})
    assert stranger.returncode == 4 and "unknown token" in stranger.stderr
    reader = nbake("submit", "cornell_box", "--kind", "render", env=env | {"NBAKE_TOKEN": TOKENS["read"]})
    assert reader.returncode == 4 and "submit" in reader.stderr


def test_url_and_token_from_a_config_file(served, tmp_path):
    config = tmp_path / "nbake.toml"
    config.write_text(f'url = "{served.grpc_url}"\ntoken = "{TOKENS["read"]}"\n')
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")}
    done = nbake("jobs", "--limit", "1", env=clean | {"NBAKE_CONFIG": str(config)})
    assert done.returncode == 0, done.stderr
    flags = nbake("jobs", "--url", "http://127.0.0.1:1", env=clean | {"NBAKE_CONFIG": str(config)})
    assert flags.returncode == 4  # a flag wins over the file


def test_kinds_and_scenes_are_the_servers_with_the_client_alone(served, tmp_path):
    """`nbake kinds` and `nbake scenes` ask the server, so a client-only install lists what it accepts."""
    from workers.models.registry import kind_names
    from workers.scene.generators.builtin import BUILTIN_SCENES

    env = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")} | {
        "NBAKE_URL": served.url,
        "NBAKE_TOKEN": TOKENS["read"],
        "NBAKE_CONFIG": str(tmp_path / "none.toml"),
    }
    scenes = lines(nbake("scenes", "--json", env=env).stdout)
    assert [scene["name"] for scene in scenes] == sorted(BUILTIN_SCENES)
    assert all(scene["description"] for scene in scenes)
    kinds = lines(nbake("kinds", "--json", env=env).stdout)
    assert sorted(kind["name"] for kind in kinds) == sorted(kind_names())
    assert all("config_schema" not in kind for kind in kinds)
    lod = lines(nbake("kinds", "lod", "--json", env=env).stdout)[0]
    assert [p["name"] for p in lod["presets"]] == ["quick", "default", "paper"]
    assert "train" in lod["config_schema"]["properties"]
    unknown = nbake("kinds", "lodd", env=env)
    assert unknown.returncode == 2 and "lodd" in unknown.stderr
    grpc = nbake("scenes", env=env | {"NBAKE_URL": served.grpc_url})
    assert grpc.returncode == 2 and "REST only" in grpc.stderr
