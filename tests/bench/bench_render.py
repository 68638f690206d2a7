"""Path tracer throughput against its limits and its peer, all measured in this run.

1. Rays/s of our path tracer on `cornell_box`, `cornell_glossy` and the environment-lit `env_lit_objects`
   (256x256, 16 spp) against raw Embree closest-hit queries on the same triangles with the same thread
   count (incoherent rays from inside the scene's bounds): the limit.
2. Against Mitsuba 3 `scalar_rgb` on the same three scenes at equal samples per pixel (time ratio).
3. At equal error: MSE x time is constant in spp for an unbiased Monte Carlo estimator, so the
   ratio of MSE x time (against a high-spp Mitsuba reference) is the ratio of the times each
   renderer needs to reach the same error; also with each render's process CPU seconds, which a loaded
   machine distorts less than wall time (cornell_box 16 spp, load ~6: wall ratio 0.77, CPU 0.71).
   Also in one thread, as thread CPU time: on a shared machine the other processes' load enters the
   wall-clock figures (and each renderer differently) but not these.
4. The first-run cost of the compiled kernels (Numba, cached on disk): a fresh process with an empty cache
   renders a tiny image twice; the first render's extra time is the compilation, paid once per machine.
   Every other figure is measured with the cache warm, after a warm-up render.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from tests.bench.common import BenchSection, median_seconds
from workers.render.camera import PinholeCamera
from workers.render.embree import RayScene
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, plan_render, render, render_item
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

THREADS = 2
SCENES = ("cornell_box", "cornell_glossy", "env_lit_objects")
RUNS = 3  # medians over this many renders (seeds)
SIZES = (128, 256)
SPPS = (16, 64)
REFERENCE_SPP = int(os.environ.get("RENDER_BENCH_REFERENCE_SPP", 1024))


def raw_embree_rays_per_second(
    positions: np.ndarray, bounds: np.ndarray, threads: int, batch: int = 1 << 16, batches: int = 16
) -> float:
    rays = RayScene(positions)
    origins, directions = (a.reshape(batches, batch, 3) for a in incoherent_rays(bounds, batches * batch))

    def run():
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: rays.intersect(origins[i], directions[i]), range(batches)))

    return batch * batches / median_seconds(run, repeats=5)


def incoherent_rays(bounds: np.ndarray, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Origins uniform inside the scene's bounds (less a 2.5% margin), directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    lo, hi = bounds
    origins = rng.uniform(lo + 0.025 * (hi - lo), hi - 0.025 * (hi - lo), (n, 3))
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def median_cpu_seconds(fn, repeats: int = 5) -> float:
    """Median thread CPU time of `fn` (after one untimed run)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.thread_time()
        fn()
        times.append(time.thread_time() - t0)
    return float(np.median(times))


class RecordedQueries:
    """An intersector that passes every query on and keeps a copy: the Embree work of a render, to be
    timed again without the path tracer around it."""

    def __init__(self, inner: RayScene) -> None:
        self.inner, self.queries = inner, []

    def intersect(self, origins, directions, t_max=None):
        self.queries.append((self.inner.intersect, origins.copy(), directions.copy(), t_max))
        return self.inner.intersect(origins, directions, t_max)

    def occluded(self, origins, directions, t_max):
        self.queries.append((self.inner.occluded, origins.copy(), directions.copy(), t_max))
        return self.inner.occluded(origins, directions, t_max)


def one_thread_cpu(name: str, scene) -> dict:
    """Raw Embree and our tracer in this thread, as rays per CPU second (128x128, 16 spp); and the share of
    the render's CPU time its own Embree queries (closest hit and shadow, replayed alone) take, which
    does not depend on how hard the incoherent reference rays are for this scene (on env_lit_objects
    most of them miss the small objects and are cheap)."""
    origins, directions = incoherent_rays(scene.bounds, 1 << 16)
    rays = RayScene(scene.positions)
    embree = len(origins) / median_cpu_seconds(lambda: rays.intersect(origins, directions))
    tracer = PathTracer(scene)
    settings = RenderSettings(spp=16, width=128, height=128, threads=1)
    camera = PinholeCamera(tracer.scene.spec.camera, settings.width, settings.height)
    plan = plan_render(camera, settings)
    traced = []

    def render_items():
        traced.append(
            sum(render_item(tracer, camera, settings, plan, *item).rays_traced for item in plan.items)
        )

    seconds = median_cpu_seconds(render_items, repeats=3)
    ours = traced[-1] / seconds
    recorder = RecordedQueries(tracer.rays)
    tracer.rays = tracer.primary = recorder
    render_items()
    queries = recorder.queries

    def replay():
        for query, o, d, t_max in queries:
            query(o, d) if t_max is None else query(o, d, t_max)

    own = median_cpu_seconds(replay, repeats=3)
    return dict(
        scene=name,
        embree_mrays_per_cpu_s=embree / 1e6,
        ours_mrays_per_cpu_s=ours / 1e6,
        ratio=ours / embree,
        own_queries_share=own / seconds,
    )


def relative_mse(image: np.ndarray, reference: np.ndarray) -> float:
    return float(np.mean((image - reference) ** 2 / (reference**2 + 1e-2)))


FIRST_RUN = """
import time
from workers.render.render import RenderSettings, render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
scene = compile_scene(get_builtin("{scene}"))
times = []
for _ in range(2):
    t = time.perf_counter()
    render(scene, RenderSettings(spp=1, width=16, height=16, threads=1))
    times.append(time.perf_counter() - t)
print(times[0] - times[1])
"""


STARTUP = """
import json, time
clocks = lambda: (time.perf_counter(), time.process_time())
stages, last = {{}}, clocks()
def stage(name):
    global last
    now = clocks()
    stages[name] = [now[0] - last[0], now[1] - last[1]]
    last = now
from neuralbake_client.cli.main import app
import services.cli.render
stage("imports")
from workers.render.render import RenderSettings, render
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import load_scene
scene = compile_scene(load_scene("{scene}")[0])
stage("scene")
settings = RenderSettings(spp={spp}, width={size}, height={size}, threads={threads})
render(scene, settings)
stage("first_render")
render(scene, settings)
stage("warm_render")
print(json.dumps(stages))
"""


def startup_stages(scene: str, size: int, spp: int) -> dict:
    """Where a fresh `nbake render` process's time goes, wall and CPU seconds by stage: the interpreter's
    start, the CLI's imports, the scene's load and compile, the first render and a warm one."""
    script = STARTUP.format(scene=scene, size=size, spp=spp, threads=THREADS)
    wall, _, stdout = timed_process([sys.executable, "-c", script])
    stages = json.loads(stdout)
    row = dict(scene=scene, size=size, spp=spp)
    row["interpreter_s"] = wall - sum(w for w, _ in stages.values())
    for name, (w, c) in stages.items():
        row[f"{name}_s"], row[f"{name}_cpu_s"] = w, c
    row["first_minus_warm_s"] = stages["first_render"][0] - stages["warm_render"][0]
    row["first_minus_warm_cpu_s"] = stages["first_render"][1] - stages["warm_render"][1]
    return row


def first_run_seconds(scene: str) -> float:
    """Compilation time of the kernels `scene` uses, in a fresh process with an empty Numba cache."""
    with tempfile.TemporaryDirectory(prefix="nbake-bench-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        out = subprocess.run(
            [sys.executable, "-c", FIRST_RUN.format(scene=scene)],
            env=env,
            check=True,
            capture_output=True,
            text=True,
        )
    return float(out.stdout.strip().splitlines()[-1])


def run() -> list[BenchSection]:
    throughput = BenchSection(f"Path tracer throughput, 256x256, 16 spp, max_depth 8, {THREADS} threads")
    compiled = {name: compile_scene(get_builtin(name)) for name in SCENES}
    for name, scene in compiled.items():
        embree = raw_embree_rays_per_second(scene.positions, scene.bounds, THREADS)
        tracer = PathTracer(scene)
        render(tracer, RenderSettings(spp=1, width=64, height=64))  # warm up
        results = [
            render(tracer, RenderSettings(spp=16, width=256, height=256, seed=s, threads=THREADS))
            for s in range(RUNS)
        ]
        ours = float(np.median([r.rays_per_second for r in results]))
        throughput.add(
            scene=name, embree_mrays_per_s=embree / 1e6, ours_mrays_per_s=ours / 1e6, ratio=ours / embree
        )
    throughput.notes.append(
        "ratio: our path tracer's rays/s (closest hit + shadow) over raw Embree closest hit"
    )
    throughput.notes.append("target: ratio >= 0.5 of raw Embree inside the path tracer")

    cpu = BenchSection("The same in one thread, rays per thread CPU second (128x128, 16 spp)")
    for name, scene in compiled.items():
        cpu.add(**one_thread_cpu(name, scene))
    cpu.notes.append("thread CPU time: load from other processes on the machine does not enter it")
    cpu.notes.append(
        "own_queries_share: the render's own Embree queries replayed alone, over the render's CPU time"
    )

    jit = BenchSection("First-run cost: compiling the kernels (fresh process, empty Numba cache)")
    for name in SCENES:
        jit.add(scene=name, compile_s=first_run_seconds(name))
    jit.notes.append("paid once per machine: the compiled kernels are cached on disk (numba cache=True)")

    startup = BenchSection(f"Start-up of a fresh `nbake render` process, by stage, {THREADS} threads")
    for name in SCENES:
        for _ in range(RUNS):
            startup.add(**startup_stages(name, 256, 16))
    startup.notes.append(
        "first_minus_warm: what the first render in a process pays beyond a warm one (Numba's registries,"
        " SciPy's BLAS with them, and loading the cached kernels); target < 0.3 s"
    )

    steady, cold = against_mitsuba(compiled)
    return [throughput, cpu, jit, startup, steady, cold]


def against_mitsuba(compiled: dict) -> tuple[BenchSection, BenchSection]:
    """Both renderers on the same scenes, sizes, spp and threads, at equal error, both ways: steady (each
    scene loaded once, the render alone timed) and cold (a fresh process paying its own start-up, scene
    load, kernel load and render, timed from outside). Figures of one (scene, size, spp) alternate between
    the two renderers, so a change in the machine's load falls on both."""
    import mitsuba as mi

    from tests.support.mitsuba_load import load_scene
    from tests.support.mitsuba_scene import mitsuba_scene_file

    title = f"Against Mitsuba 3 scalar_rgb, max_depth 8, both on {THREADS} threads, {cpu_model()}"
    steady = BenchSection(f"{title}: steady state (scenes loaded once, render only)")
    cold = BenchSection(f"{title}: cold (a fresh process: start-up, scene load, kernels, render)")
    with tempfile.TemporaryDirectory(prefix="nbake-bench-") as workdir:
        for name, scene in compiled.items():
            for size in SIZES:
                folder = Path(workdir) / f"{name}_{size}"
                scene_file = mitsuba_scene_file(scene, folder, REFERENCE_SPP, 8, width=size, height=size)
                loaded = load_scene(scene_file, THREADS)
                t0 = time.perf_counter()
                reference = mitsuba_image(mi.render(loaded, spp=REFERENCE_SPP, seed=1000))
                steady.notes.append(
                    f"{name} {size}x{size} reference: Mitsuba {REFERENCE_SPP} spp in "
                    f"{time.perf_counter() - t0:.1f} s"
                )
                tracer = PathTracer(scene)
                render(tracer, RenderSettings(spp=1, width=size, height=size, threads=THREADS))  # warm up
                mi.render(loaded, spp=1, seed=0)
                for spp in SPPS:
                    row = steady_row(name, size, spp, tracer, loaded, reference)
                    steady.add(**row)
                    cold.add(**cold_row(name, size, spp, folder, scene_file, row))
    steady.notes += [
        "speedup > 1: we are faster; at equal error = (time x relMSE) Mitsuba / ours (MSE x time is constant"
        " in spp for an unbiased estimator), relMSE against the reference, medians of "
        f"{RUNS} seeds",
        "cpu_: the same with process CPU seconds (both renderers run in this process): other processes' load"
        " enters it less than wall time",
        f"the reference's own noise (~relMSE at 16 spp x 16/{REFERENCE_SPP}) adds to both errors alike",
        "target: speedup_at_equal_error >= 1.5 on every scene at 256x256",
    ]
    cold.notes += [
        "ours: `nbake render SCENE --no-png` in a fresh process; mitsuba: a fresh python running "
        "tests/support/mitsuba_load.py (import, load_dict of a JSON scene + PLY files, render, write the EXR)"
        "; both write one EXR; wall and CPU (the child's user + sys) from outside; error as in steady state",
        "ours_first_render_s: the render time `nbake render` reports (its first render in the process);"
        " ours_warm_s: the steady-state render of the same image; start-up target: first - warm < 0.3 s",
    ]
    return steady, cold


def steady_row(name: str, size: int, spp: int, tracer: PathTracer, loaded, reference: np.ndarray) -> dict:
    """One steady-state comparison: `RUNS` seeds, alternating between the renderers; medians."""
    import mitsuba as mi

    ours, theirs = [], []
    for seed in range(RUNS):
        settings = RenderSettings(spp=spp, width=size, height=size, seed=seed, threads=THREADS)
        ours.append(timed(reference, lambda: render(tracer, settings).image))  # noqa: B023 (called here)
        theirs.append(timed(reference, lambda: mi.render(loaded, spp=spp, seed=seed)))  # noqa: B023
    (to, co, eo), (tm, cm, em) = (np.median(np.array(x), axis=0) for x in (ours, theirs))
    return dict(
        scene=name,
        size=size,
        spp=spp,
        ours_s=to,
        mitsuba_s=tm,
        ours_relmse=eo,
        mitsuba_relmse=em,
        speedup=tm / to,
        speedup_at_equal_error=(tm * em) / (to * eo),
        cpu_speedup_at_equal_error=(cm * em) / (co * eo),
    )


def cold_row(name: str, size: int, spp: int, folder: Path, scene_file: Path, steady: dict) -> dict:
    """One cold comparison: `RUNS` fresh processes each side, alternating; medians."""
    nbake = Path(sys.executable).with_name("nbake")
    loader = Path(__file__).resolve().parents[1] / "support" / "mitsuba_load.py"
    ours, theirs = [], []
    for seed in range(RUNS):
        args = [
            f"--spp={spp}",
            f"--width={size}",
            f"--height={size}",
            f"--threads={THREADS}",
            f"--seed={seed}",
        ]
        out = folder / f"ours_{spp}.exr"
        wall, cpu, stdout = timed_process(
            [str(nbake), "render", name, *args, "-o", str(out), "--no-png", "--json"]
        )
        first = json.loads(stdout.strip().splitlines()[-1])["seconds"]
        ours.append((wall, cpu, first))
        out = folder / f"mitsuba_{spp}.exr"
        wall, cpu, _ = timed_process(
            [sys.executable, str(loader), str(scene_file), str(out), str(spp), str(seed), str(THREADS)]
        )
        theirs.append((wall, cpu))
    (to, co, first), (tm, cm) = (np.median(np.array(x), axis=0) for x in (ours, theirs))
    error_ratio, warm = steady["ours_relmse"] / steady["mitsuba_relmse"], steady["ours_s"]
    return dict(
        scene=name,
        size=size,
        spp=spp,
        ours_s=to,
        mitsuba_s=tm,
        speedup_at_equal_error=tm / (to * error_ratio),
        cpu_speedup_at_equal_error=cm / (co * error_ratio),
        ours_first_render_s=first,
        ours_warm_s=warm,
        first_minus_warm_s=first - warm,
        process_minus_warm_s=to - warm,
    )


def timed(reference: np.ndarray, render_image) -> tuple[float, float, float]:
    """(wall seconds, process CPU seconds, relMSE against `reference`) of one render."""
    t, c = time.perf_counter(), time.process_time()
    image = render_image()
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    return wall, cpu, relative_mse(mitsuba_image(image), reference)


def timed_process(command: list[str]) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds of the child, its stdout) of a fresh process, from outside."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    done = subprocess.run(command, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, done.stdout


def mitsuba_image(image) -> np.ndarray:
    """An (H, W, 3) float64 array of a Mitsuba tensor (or our float32 image)."""
    return np.array(image, dtype=np.float64)[..., :3]


def cpu_model() -> str:
    """The CPU's model name (lscpu's), which the figures depend on."""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"
