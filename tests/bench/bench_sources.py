"""Samples/s of the training sample sources that run on the path tracer's kernels, in the sampler actor's
loop: `LodSource.batch` (voxel pairs, Embree visibility and voxel-confined appearance paths) and
`ObjectRaySource.batch` (lsnif training rays and their Embree labels), at the `default` preset.

One source object per kind, built and warmed up (grid, voxels, Embree BVH, compiled kernels) before timing;
the figure is the preset's batch size over the median thread CPU seconds of a batch, over distinct batch
indices: a batch runs in the calling thread, and CPU time leaves out the load of other processes on a shared
machine. Run it on two checkouts in one window to compare them (issue 19 reports before and after this way).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from tests.bench.common import BenchSection
from workers.models.lod import KIND as LOD
from workers.models.lod.grid import LodGrid
from workers.models.lod.plan import choose_asset, choose_resolutions, cube_extent
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_triangles
from workers.models.lsnif import KIND as LSNIF
from workers.models.lsnif.sampling import ObjectRaySource, ObjectSourceConfig
from workers.scene.builtin import get_builtin
from workers.scene.reference import SceneRef

BATCHES = 7  # timed batches per source (after one warm-up batch)
LOD_SCENES = ("menger_sponge", "dense_foliage")
LSNIF_SCENES = (("high_poly", "displaced_sphere"), ("dense_foliage", "leaves"))


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


def run() -> list[BenchSection]:
    section = BenchSection(f"Sample sources at the default preset (median CPU time of {BATCHES} batches)")
    for name in LOD_SCENES:
        source, size = lod_source(name)
        seconds = seconds_per_batch(source)
        section.add(source="lod", scene=name, batch=size, batch_cpu_s=seconds, samples_per_s=size / seconds)
    for name, obj in LSNIF_SCENES:
        source, size = lsnif_source(name, obj)
        seconds = seconds_per_batch(source)
        section.add(
            source="lsnif",
            scene=f"{name}/{obj}",
            batch=size,
            batch_cpu_s=seconds,
            samples_per_s=size / seconds,
        )
    section.notes.append("samples: voxel pairs (lod) or training rays (lsnif) per batch")
    return [section]
