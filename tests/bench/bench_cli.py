"""`nbake` start-up: the wall time of `nbake --help` and of `nbake show JOB` (answered by an API-only job
server in this process, which needs Ray initialised, so the figure is start-up plus one request) against
`python -c pass` in the same run. Target: under 0.5 s above the bare interpreter. The remote commands
import neither torch nor the server; this measures what is left (typer, rich, httpx, pydantic)."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import httpx
import ray

from tests.bench.common import BenchSection, median_seconds
from tests.integration.test_api_server import NBAKE, TOKENS, DatabaseChoice, ServerThread, settings_for

REPEATS = 9


def _timed(command: list[str], env: dict | None = None) -> float:
    def run() -> None:
        subprocess.run(command, check=True, capture_output=True, env=env, timeout=60)

    return median_seconds(run, repeats=REPEATS, warmup=2)


def run() -> list[BenchSection]:
    section = BenchSection(f"nbake start-up (median of {REPEATS} runs)")
    with tempfile.TemporaryDirectory(prefix="nbake-bench-cli-", dir="/tmp") as root:
        ray.init(num_cpus=1, include_dashboard=False, _temp_dir=f"{root}/ray", log_to_driver=False)
        settings = settings_for(Path(root), DatabaseChoice("sqlite", None), scheduling=False)
        with ServerThread(settings) as server:
            headers = {"Authorization": f"Bearer {TOKENS['admin']}"}
            job = {"kind": "render", "scene": "cornell_box", "preset": "quick"}
            job_id = httpx.post(f"{server.url}/v1/jobs", json=job, headers=headers, timeout=60).json()["id"]
            env = {
                "NBAKE_URL": server.url,
                "NBAKE_TOKEN": TOKENS["read"],
                "NBAKE_CONFIG": f"{root}/none.toml",
            }
            bare = _timed([sys.executable, "-c", "pass"])
            for label, command in (
                ("python -c pass", None),
                ("nbake --help", [NBAKE, "--help"]),
                ("nbake show JOB --json", [NBAKE, "show", job_id, "--json"]),
            ):
                seconds = bare if command is None else _timed(command, env)
                section.add(command=label, seconds=seconds, above_python_s=seconds - bare)
        ray.shutdown()
    section.notes.append("target: under 0.5 s above `python -c pass` on this machine")
    return [section]
