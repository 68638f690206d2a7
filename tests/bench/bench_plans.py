"""Plans against what jobs take: every kind's `quick` preset on its Example scene, submitted to a real
`nbake serve` (its own local Ray cluster), timed from POST to SUCCEEDED, against the plan's estimate; and
the per-unit costs of `workers.runtime.fixed_costs`, each measured in a fresh interpreter.

A warm-up job per kind runs first, untimed, so Numba's kernels are in the machine's cache (a plan counts
their load, not their compilation, which happens once per machine). The figures go to the bench report
and to the generated table of `docs/results/plans.md`, with the CPU model and the load during the run:
the machine may be shared, which inflates the measured times and not the plans.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import httpx

from tests.bench.common import BenchSection
from tests.integration.test_api_server import TOKENS, TOKENS_ENV, events
from tests.support.cluster import ServeReplica
from workers.models.registry import get_kind, kind_names

RUNS = int(os.environ.get("NBAKE_BENCH_PLAN_RUNS", "3"))  # timed jobs a kind, after one warm-up
JOB_TIMEOUT_S = 1800
RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results" / "plans.md"
BEGIN, END = "<!-- bench_plans: begin -->", "<!-- bench_plans: end -->"


def run() -> list[BenchSection]:
    units = unit_costs()
    section = BenchSection(f"Plans against jobs through `nbake serve`: quick presets (median of {RUNS})")
    load_before = load_average()
    with tempfile.TemporaryDirectory(prefix="nbake-bench-plans-", dir="/tmp") as root:
        env = {"NBAKE_TOKENS": TOKENS_ENV}
        server = ServeReplica(Path(root) / "data", env)
        try:
            server.start()
            with httpx.Client(
                base_url=server.url, headers={"Authorization": f"Bearer {TOKENS['admin']}"}, timeout=120
            ) as client:
                for name in kind_names():
                    section.add(**measure_kind(client, name))
        finally:
            server.stop()
    section.notes += [
        f"CPU: {cpu_model()}, {os.cpu_count()} cores; load average {load_before} before, "
        f"{load_average()} after (other work on the machine inflates `measured_s`, not `planned_s`)",
        "measured: wall time from POST /v1/jobs to SUCCEEDED, after one untimed warm-up job per kind; "
        "hand-off: from RUNNING to the kind's first log line (median)",
        "target: ratio (measured / planned) within 0.5-2",
    ]
    write_results([units, section])
    return [units, section]


def unit_costs() -> BenchSection:
    section = BenchSection("Fixed costs' per-unit figures (workers/runtime/fixed_costs.py), a fresh process")
    load_before = load_average()
    output = subprocess.run(
        [sys.executable, "-c", "from tests.bench.bench_plans import probe; probe()"],
        capture_output=True, text=True, check=True, timeout=1200,
    ).stdout  # fmt: skip
    for name, value in json.loads(output.splitlines()[-1]).items():
        section.add(figure=name, value=value)
    # what a driver imports before its kind's first line: `render`'s, and a kind that trains
    for module in ("torch", "workers.models.render.run", "workers.models.lsnif.run"):
        section.add(figure=f"import_s_{module}", value=import_seconds(module))
    section.notes.append(f"CPU: {cpu_model()}; load average {load_before} before, {load_average()} after")
    return section


def import_seconds(module: str) -> float:
    """Seconds to import `module` in a fresh interpreter."""
    code = f"import time; t = time.perf_counter(); import {module}; print(time.perf_counter() - t)"
    command = [sys.executable, "-c", code]
    return float(subprocess.run(command, capture_output=True, text=True, check=True).stdout.split()[-1])


def probe() -> None:
    """Print the per-unit costs as JSON: the kernels' load in this process (its first render), a scene's
    compile per triangle, a mesh file's read per byte, path tracing per sample and its rays."""
    import numpy as np
    import trimesh

    from workers.render.integrator import PathTracer
    from workers.render.render import RenderSettings, render
    from workers.scene.format import spec
    from workers.scene.generators.builtin import get_builtin
    from workers.scene.geometry.compile import compile_scene
    from workers.scene.geometry.shapes import shape_mesh

    figures = {}
    tracer = PathTracer(compile_scene(get_builtin("cornell_box")))
    tiny = RenderSettings(spp=1, width=8, height=8, seed=0, threads=1)
    first, second = (render(tracer, tiny).seconds for _ in range(2))
    figures["kernel_load_s"] = first - second
    for name in ("menger_sponge", "fur_patch"):
        started = time.perf_counter()
        scene = compile_scene(get_builtin(name))
        PathTracer(scene)
        figures[f"compile_s_per_triangle_{name}"] = (time.perf_counter() - started) / scene.num_triangles
    with tempfile.TemporaryDirectory() as folder:  # fur_patch's triangles as a PLY file
        n, path = scene.num_triangles, Path(folder) / "mesh.ply"
        trimesh.Trimesh(scene.positions.reshape(-1, 3), np.arange(3 * n).reshape(n, 3), process=False).export(
            path
        )
        started = time.perf_counter()
        shape_mesh(spec.MeshShape(path=path.name), "shape", path.parent)
        figures["mesh_read_s_per_byte"] = (time.perf_counter() - started) / path.stat().st_size
    for name, depth in (("cornell_box", 8), ("env_lit_objects", 5), ("menger_sponge", 64)):
        tracer = PathTracer(compile_scene(get_builtin(name)))
        settings = RenderSettings(spp=64, width=32, height=32, max_depth=depth, seed=0, threads=1)
        render(tracer, settings.model_copy(update={"spp": 1}))
        result = render(tracer, settings)
        figures[f"s_per_sample_{name}_depth_{depth}"] = result.seconds / (32 * 32 * 64)
        figures[f"rays_per_sample_{name}_depth_{depth}"] = result.rays_traced / (32 * 32 * 64)
    print(json.dumps(figures))


def measure_kind(client: httpx.Client, name: str) -> dict:
    example = get_kind(name).example
    body = {"kind": name, "scene": example.scene, "preset": "quick", "config": example.overrides}
    planned, seconds, handoffs = 0.0, [], []
    for attempt in range(RUNS + 1):
        started = time.perf_counter()
        response = client.post("/v1/jobs", json={**body, "seed": attempt})
        response.raise_for_status()
        job = response.json()
        planned = job["plan"]["estimated_seconds"]
        done = wait_finished(client, job["id"])
        if done["state"] != "SUCCEEDED":  # the row says so; the other kinds are still measured
            return {"kind": name, "scene": example.scene, "planned_s": planned, "error": done.get("error")}
        if attempt:  # the first is the warm-up
            seconds.append(time.perf_counter() - started)
            handoffs.append(handoff_seconds(events(client, job["id"])))
    measured = statistics.median(seconds)
    return {
        "kind": name,
        "scene": example.scene,
        "planned_s": planned,
        "measured_s": measured,
        "runs_s": " ".join(f"{s:.1f}" for s in seconds),
        "handoff_s": statistics.median(handoffs),
        "ratio": measured / planned,
    }


def handoff_seconds(job_events: list[dict]) -> float:
    """From RUNNING to the kind's first log line (one the driver timestamps): the hand-off and imports."""
    times = {
        "running": next(e["time"] for e in job_events if e["data"].get("state") == "RUNNING"),
        "first": next(e["time"] for e in job_events if e["type"] == "log" and "time" in e["data"]),
    }
    running, first = (datetime.fromisoformat(times[k]) for k in ("running", "first"))
    return (first - running).total_seconds()


def wait_finished(client: httpx.Client, job_id: str) -> dict:
    deadline = time.monotonic() + JOB_TIMEOUT_S
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in {"SUCCEEDED", "FAILED", "CANCELLED"}:
            return job
        time.sleep(0.2)
    raise TimeoutError(f"job {job_id} did not finish within {JOB_TIMEOUT_S} s")


def load_average() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def cpu_model() -> str:
    output = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
    model = next((line.split(":", 1)[1] for line in output.splitlines() if line.startswith("Model name")), "")
    return model.strip() or platform.processor() or "unknown"


def write_results(sections: list[BenchSection]) -> None:
    """Replace the generated tables of `docs/results/plans.md` (between its markers) with this run's."""
    units, section = sections
    table = "\n".join(
        [
            f"Per-unit figures, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}:",
            "",
            "| figure | value |",
            "| --- | --- |",
            *(f"| {r['figure']} | {r['value']:.3g} |" for r in units.rows),
            "",
            *(f"- {note}" for note in units.notes),
            "",
            f"Run {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} (`python -m tests.bench bench_plans`, "
            f"{RUNS} timed run(s) a kind):",
            "",
            "| kind | scene | planned s | measured s (median) | runs s | measured / planned | hand-off s |",
            "| --- | --- | --- | --- | --- | --- | --- |",
            *(
                f"| {r['kind']} | {r['scene']} | {r['planned_s']:.1f} | {r['measured_s']:.1f} "
                f"| {r['runs_s']} | {r['ratio']:.2f} | {r['handoff_s']:.1f} |"
                if "error" not in r
                else f"| {r['kind']} | {r['scene']} | {r['planned_s']:.1f} | failed: {r['error']} | | | |"
                for r in section.rows
            ),
            "",
            *(f"- {note}" for note in section.notes),
        ]
    )
    text = RESULTS.read_text()
    head, _, rest = text.partition(BEGIN)
    _, _, tail = rest.partition(END)
    RESULTS.write_text(f"{head}{BEGIN}\n{table}\n{END}{tail}")
