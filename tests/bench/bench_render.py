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

import os
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

    peer = BenchSection("Against Mitsuba 3 scalar_rgb, 128x128, max_depth 8")
    with tempfile.TemporaryDirectory(prefix="nbake-bench-") as workdir:
        for name, scene in compiled.items():
            against_mitsuba(peer, name, scene, Path(workdir))
    peer.notes.append("ratios > 1 mean we are slower; equal-error ratio = (MSE x time) ours / Mitsuba")
    peer.notes.append("Mitsuba time includes scene loading (PLY export excluded), as a user would pay it")
    peer.notes.append(
        "cpu_ratio_at_equal_error: the same with process CPU seconds (both renderers run in this process on "
        f"{THREADS} threads): other processes' load does not enter it, a thread left idle at the end does"
        " not either"
    )
    peer.notes.append("target: equal-error ratio <= 1 / 1.5 on every scene")
    return [throughput, cpu, jit, peer]


def against_mitsuba(peer: BenchSection, name: str, compiled, workdir: Path) -> None:
    from tests.support.mitsuba_scene import render_mitsuba

    size = 128
    tracer = PathTracer(compiled)
    t0 = time.perf_counter()
    reference = np.mean(
        [render_mitsuba(compiled, workdir, 512, 8, seed=100 + s, width=size, height=size) for s in range(4)],
        axis=0,
    )
    peer.notes.append(f"{name} reference: Mitsuba 2048 spp in {time.perf_counter() - t0:.1f} s")
    for spp in (16, 64):
        t_ours, cpu_ours, err_ours = [], [], []
        for seed in range(RUNS):
            c = time.process_time()
            r = render(tracer, RenderSettings(spp=spp, width=size, height=size, seed=seed, threads=THREADS))
            cpu_ours.append(time.process_time() - c)
            t_ours.append(r.seconds)
            err_ours.append(relative_mse(r.image.astype(np.float64), reference))
        t_mi, cpu_mi, err_mi = [], [], []
        for seed in range(RUNS):
            t, c = time.perf_counter(), time.process_time()
            image = render_mitsuba(compiled, workdir, spp, 8, seed=seed, width=size, height=size)
            t_mi.append(time.perf_counter() - t)
            cpu_mi.append(time.process_time() - c)
            err_mi.append(relative_mse(image, reference))
        to, tm = float(np.median(t_ours)), float(np.median(t_mi))
        co, cm = float(np.median(cpu_ours)), float(np.median(cpu_mi))
        eo, em = float(np.median(err_ours)), float(np.median(err_mi))
        peer.add(
            scene=name,
            spp=spp,
            ours_s=to,
            mitsuba_s=tm,
            time_ratio=to / tm,
            ours_relmse=eo,
            mitsuba_relmse=em,
            time_ratio_at_equal_error=(to * eo) / (tm * em),
            cpu_ratio_at_equal_error=(co * eo) / (cm * em),
        )
