"""`nbake` as the client package builds it: the remote commands start without the server's code (a fresh
interpreter's `sys.modules` after the command ran), the server package's commands join through the
`neuralbake.cli` entry point, and `nbake render` sends an artifact to the inference service and a scene to
the local path tracer, or explains what is missing when only the client is installed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from neuralbake_client.cli import plugins
from neuralbake_client.cli.main import app
from neuralbake_client.cli.render import first_positional
from typer.testing import CliRunner

from tests.support.ports import free_port

HEAVY = {"torch", "ray", "embreex", "workers", "numpy", "grpc", "httpx", "pydantic"}
PLUGIN = {"services", "services.cli", "services.cli.plugin"}  # the server's registration: names only

# Runs `nbake ARGS...` in this interpreter and writes the imported module names to the file in argv[1].
RUN_AND_LIST_MODULES = """
import atexit, json, sys
out, sys.argv = sys.argv[1], ["nbake", *sys.argv[2:]]
atexit.register(lambda: open(out, "w").write(json.dumps(sorted(sys.modules))))
from neuralbake_client.cli.main import app
app()
"""


def modules_after(tmp_path: Path, *args: str) -> set[str]:
    listing = tmp_path / "modules.json"
    env = {"NBAKE_CONFIG": str(tmp_path / "none.toml"), "PATH": "/usr/bin:/bin"}
    done = subprocess.run(
        [sys.executable, "-c", RUN_AND_LIST_MODULES, str(listing), *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=env,
    )
    assert "Traceback" not in done.stderr, done.stderr
    return set(json.loads(listing.read_text()))


def heavy(modules: set[str]) -> set[str]:
    return {name.split(".")[0] for name in modules} & HEAVY | {m for m in modules if m.startswith("services")}


def test_remote_commands_import_neither_torch_nor_the_server(tmp_path):
    assert heavy(modules_after(tmp_path, "--help")) == PLUGIN
    unreachable = f"http://127.0.0.1:{free_port()}"
    shown = modules_after(tmp_path, "show", "job-x", "--url", unreachable, "--json")
    assert heavy(shown) == {"httpx", "pydantic"}
    rendered = modules_after(tmp_path, "render", "sha256:" + "0" * 64, "-o", "x.png", "--url", unreachable)
    assert heavy(rendered) == {"httpx", "pydantic", "numpy"}


def test_a_local_render_loads_neither_torch_nor_ray(tmp_path):
    """The model kinds (torch, Ray) are loaded only for a scene with a kind's material, the store's
    filesystems (fsspec) only to fetch from it: importing them was most of `nbake render`'s start-up
    (tests/bench/bench_render.py times it)."""
    small = ["--spp", "1", "--width", "8", "--height", "8", "--threads", "1", "--no-png"]
    rendered = modules_after(tmp_path, "render", "cornell_box", *small, "-o", "x.exr")
    assert "workers.render.render" in rendered
    assert {name.split(".")[0] for name in rendered} & {"torch", "ray", "fsspec"} == set()


def test_the_server_package_adds_its_commands_with_their_own_summaries():
    (server,) = plugins.installed()
    help_text = CliRunner().invoke(app, ["--help"]).stdout
    for ref in (*server.commands, server.scene_render):
        loaded = ref.load()
        assert ref.summary == loaded.help.strip().splitlines()[0], ref.name
        assert ref.name in help_text
    serve_help = CliRunner().invoke(app, ["serve", "--help"])
    assert serve_help.exit_code == 0 and "--inference-port" in serve_help.stdout


def test_render_sends_artifacts_to_the_inference_service_and_scenes_to_the_path_tracer(monkeypatch):
    local = CliRunner().invoke(app, ["render", "cornell_box", "--help"])
    assert local.exit_code == 0 and "--spp" in local.stdout
    remote = CliRunner().invoke(app, ["render", "-o", "x.exr", "sha256:abc", "--help"])
    assert remote.exit_code == 0 and "--camera" in remote.stdout and "--spp" not in remote.stdout

    monkeypatch.setattr(plugins, "installed", lambda: ())  # only the client package
    alone = CliRunner().invoke(app, ["render", "cornell_box"])
    assert alone.exit_code == 2 and "needs the server package" in alone.stderr
    assert "Serve the REST API" not in CliRunner().invoke(app, ["--help"]).stdout
    assert CliRunner().invoke(app, ["serve"]).exit_code == 2  # no such command


@pytest.mark.parametrize(
    ("args", "target"),
    [
        (["sha256:1", "-o", "x.exr"], "sha256:1"),
        (["-o", "x.exr", "sha256:1"], "sha256:1"),
        (["--output=x.exr", "job-1"], "job-1"),
        (["--spp", "4", "cornell_box"], "4"),  # an option we do not know is taken as a flag
        (["--json", "scene.yaml"], "scene.yaml"),
        (["--help"], None),
    ],
)
def test_first_positional_skips_option_values(args, target):
    assert first_positional(args, {"-o", "--output", "--camera"}) == target
