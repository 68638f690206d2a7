"""Path tracer throughput against its limits and its peer, all measured in this run.

1. Rays/s of our path tracer on `cornell_box` (256x256) against raw Embree closest-hit queries on
   the same triangles with the same thread count (incoherent rays from inside the box): the limit.
2. Against Mitsuba 3 `scalar_rgb` at equal samples per pixel (time ratio).
3. At equal error: MSE x time is constant in spp for an unbiased Monte Carlo estimator, so the
   ratio of MSE x time (against a high-spp Mitsuba reference) is the ratio of the times each
   renderer needs to reach the same error.
"""

from __future__ import annotations

import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from tests.bench.common import BenchSection, median_seconds
from workers.render.embree import RayScene
from workers.render.render import RenderSettings, render
from workers.scene.builtin import cornell_box
from workers.scene.compile import compile_scene

THREADS = 2


def raw_embree_rays_per_second(
    positions: np.ndarray, threads: int, batch: int = 1 << 16, batches: int = 16
) -> float:
    rays = RayScene(positions)
    rng = np.random.default_rng(0)
    origins = rng.uniform(-0.95, 0.95, (batches, batch, 3))
    directions = rng.normal(size=(batches, batch, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)

    def run():
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: rays.intersect(origins[i], directions[i]), range(batches)))

    return batch * batches / median_seconds(run, repeats=5)


def relative_mse(image: np.ndarray, reference: np.ndarray) -> float:
    return float(np.mean((image - reference) ** 2 / (reference**2 + 1e-2)))


def run() -> list[BenchSection]:
    compiled = compile_scene(cornell_box())
    throughput = BenchSection("Path tracer throughput, cornell_box 256x256, 16 spp, max_depth 8")
    embree = raw_embree_rays_per_second(compiled.positions, THREADS)
    settings = RenderSettings(spp=16, width=256, height=256, threads=THREADS)
    render(compiled, RenderSettings(spp=1, width=64, height=64))  # warm up
    results = [render(compiled, settings) for _ in range(3)]
    ours = float(np.median([r.rays_per_second for r in results]))
    throughput.add(what=f"raw Embree closest hit ({THREADS} threads)", mrays_per_s=embree / 1e6, ratio=1.0)
    throughput.add(what="neuralbake path tracer (NEE+MIS)", mrays_per_s=ours / 1e6, ratio=ours / embree)
    throughput.notes.append("target: ratio >= 0.35 of raw Embree inside the path tracer")

    with tempfile.TemporaryDirectory(prefix="nbake-bench-") as workdir:
        peer = against_mitsuba(compiled, Path(workdir))
    return [throughput, peer]


def against_mitsuba(compiled, workdir: Path) -> BenchSection:
    from tests.support.mitsuba_scene import render_mitsuba

    peer = BenchSection("Against Mitsuba 3 scalar_rgb, cornell_box 128x128, max_depth 8")
    size = 128
    t0 = time.perf_counter()
    reference = np.mean(
        [render_mitsuba(compiled, workdir, 512, 8, seed=100 + s, width=size, height=size) for s in range(4)],
        axis=0,
    )
    peer.notes.append(f"reference: Mitsuba 2048 spp in {time.perf_counter() - t0:.1f} s")
    for spp in (16, 64):
        t_ours = []
        err_ours = []
        for seed in range(3):
            r = render(compiled, RenderSettings(spp=spp, width=size, height=size, seed=seed, threads=THREADS))
            t_ours.append(r.seconds)
            err_ours.append(relative_mse(r.image.astype(np.float64), reference))
        t_mi, err_mi = [], []
        for seed in range(3):
            t = time.perf_counter()
            image = render_mitsuba(compiled, workdir, spp, 8, seed=seed, width=size, height=size)
            t_mi.append(time.perf_counter() - t)
            err_mi.append(relative_mse(image, reference))
        to, tm = float(np.median(t_ours)), float(np.median(t_mi))
        eo, em = float(np.median(err_ours)), float(np.median(err_mi))
        peer.add(
            spp=spp,
            ours_s=to,
            mitsuba_s=tm,
            time_ratio=to / tm,
            ours_relmse=eo,
            mitsuba_relmse=em,
            time_ratio_at_equal_error=(to * eo) / (tm * em),
        )
    peer.notes.append("ratios > 1 mean we are slower; equal-error ratio = (MSE x time) ours / Mitsuba")
    peer.notes.append("Mitsuba time includes scene loading (PLY export excluded), as a user would pay it")
    return peer
