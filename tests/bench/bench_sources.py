"""Samples/s of the training sample sources that run on the path tracer's kernels, in the sampler actor's
loop: `LodSource.batch` (voxel pairs, Embree visibility and voxel-confined appearance paths) and
`ObjectRaySource.batch` (lsnif training rays and their Embree labels), at the `default` preset.

One source object per kind, built and warmed up (grid, voxels, Embree BVH, compiled kernels) before timing;
the figure is the preset's batch size over the median thread CPU seconds of a batch, over distinct batch
indices: a batch runs in the calling thread, and CPU time leaves out the load of other processes on a shared
machine.

`BENCH_SOURCES_PEER=<checkout>` also measures another checkout of the repository in the same window (e.g. a
worktree of `fb3938e^`, the tracer before issue 19's compiled kernels): this file runs as a script in a
fresh process per tree with that tree first on the path, alternating trees for `PEER_ROUNDS` rounds; the
rows then carry both trees' medians over the rounds and the speedup. The peer needs the same source API
(`LodSource`, `ObjectRaySource` and their configs), which has not changed since before issue 19.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from workers.models.lod import KIND as LOD
from workers.models.lod.grid import LodGrid
from workers.models.lod.plan import choose_asset, choose_resolutions, cube_extent
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_triangles
from workers.models.lsnif import KIND as LSNIF
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

BATCHES = 7  # timed batches per source (after one warm-up batch)
PEER_ROUNDS = 3  # alternating processes per tree with BENCH_SOURCES_PEER
LOD_SCENES = ("menger_sponge", "dense_foliage")
LSNIF_SCENES = (("high_poly", "displaced_sphere"), ("dense_foliage", "leaves"))
REPO = Path(__file__).resolve().parents[2]


def lod_source(scene_name: str) -> tuple[LodSource, int]:
    """The `default` preset's source on the asset `lod` would choose in the built-in scene."""
    config = LOD.resolve_config("default", {})
    ref = SceneRef(get_builtin(scene_name))
    asset = choose_asset(ref, config)
    scene = ref.compiled()
    extent = cube_extent(asset.bounds, config.finest_resolution)
    resolutions = [r for r, _ in choose_resolutions(ref.spec, config, extent)]
    grid = LodGrid.build(scene.positions[asset_triangles(scene, asset.names)].astype(np.float64), resolutions)
    return LodSource(LodSourceConfig(ref, asset.names, config, grid.arrays()), seed=0), config.batch_size


def lsnif_source(scene_name: str, object_name: str) -> tuple[ObjectRaySource, int]:
    config = LSNIF.resolve_config("default", {})
    spec = get_builtin(scene_name)
    index = [o.name for o in spec.objects].index(object_name)
    source = ObjectRaySource(ObjectSourceConfig(SceneRef(spec), index, config), seed=0)
    return source, config.batch_size


def seconds_per_batch(source) -> float:
    """Median thread CPU seconds of a batch."""
    source.batch(0)  # warm-up: lazy preparation, BVH build, kernels
    times = []
    for index in range(1, BATCHES + 1):
        t0 = time.thread_time()
        source.batch(index)
        times.append(time.thread_time() - t0)
    return statistics.median(times)


def measure() -> list[dict]:
    """One row per source: kind, scene, batch size and median CPU seconds of a batch."""
    rows = []
    for name in LOD_SCENES:
        source, size = lod_source(name)
        rows.append(dict(source="lod", scene=name, batch=size, batch_cpu_s=seconds_per_batch(source)))
    for name, obj in LSNIF_SCENES:
        source, size = lsnif_source(name, obj)
        rows.append(
            dict(source="lsnif", scene=f"{name}/{obj}", batch=size, batch_cpu_s=seconds_per_batch(source))
        )
    return rows


def measure_in_process(tree: Path) -> list[dict]:
    """`measure()` in a fresh process that imports the repository at `tree`."""
    path = os.pathsep.join([str(tree), str(tree / "clients" / "python"), os.environ.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, __file__],
        cwd=tree,
        env={**os.environ, "PYTHONPATH": path},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def run() -> list:
    from tests.bench.common import BenchSection

    peer = os.environ.get("BENCH_SOURCES_PEER")
    if peer is None:
        section = BenchSection(f"Sample sources at the default preset (median CPU time of {BATCHES} batches)")
        for row in measure():
            section.add(**row, samples_per_s=row["batch"] / row["batch_cpu_s"])
    else:
        section = BenchSection(
            f"Sample sources against {peer} (median over {PEER_ROUNDS} alternating processes per tree of "
            f"the median CPU time of {BATCHES} batches)"
        )
        rounds = {"ours": [], "peer": []}
        for _ in range(PEER_ROUNDS):
            rounds["ours"].append(measure_in_process(REPO))
            rounds["peer"].append(measure_in_process(Path(peer).resolve()))
        for i, row in enumerate(rounds["ours"][0]):
            ours = statistics.median(r[i]["batch_cpu_s"] for r in rounds["ours"])
            theirs = statistics.median(r[i]["batch_cpu_s"] for r in rounds["peer"])
            section.add(
                source=row["source"],
                scene=row["scene"],
                batch=row["batch"],
                samples_per_s=row["batch"] / ours,
                peer_samples_per_s=row["batch"] / theirs,
                speedup=theirs / ours,
            )
        section.notes.append("target (issue 19): speedup >= 2 against the tracer before the issue")
    section.notes.append("samples: voxel pairs (lod) or training rays (lsnif) per batch")
    return [section]


if __name__ == "__main__":  # a tree's figures for BENCH_SOURCES_PEER, as one JSON line
    print(json.dumps(measure()))
