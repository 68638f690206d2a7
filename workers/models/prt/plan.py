"""What a scene needs from `prt`: the cube map and K, the hash grid's box, which objects' indirect light
is modelled (a short probe path trace), the memory of S, W, U and f, and the cost.

The probe (`probe`) decides which objects' indirect light is modelled.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from workers.models.prt.config import PrtConfig
from workers.models.prt.data import scene_box
from workers.models.prt.probe import probe_objects
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import fixed_costs, report_view
from workers.scene.portability.reference import SceneRef

# Measured on this 2-core CPU (prt17, one thread, beside two default jobs): a default job's 147k
# rows at 128 spp took 0.54-0.62 CPU s a view, 96 views, ~320k binned paths a second. (The figures before,
# 40k paths and 90k pairs a second, were taken under a load of ~15 with older code: a default job's plan
# said 5000 s for a job of ~600.) A job's fixed costs are `fixed_costs`'s; the probe and a step's own
# overhead are not counted: a quick job planned at 0.6 s took 14 s through `nbake serve`, 6 of them before
# its rows.
PATHS_PER_SECOND = 300_000.0
# Pixel-wavelet pairs through f per second at M = 16, forward and backward: a default step (128 pixels x
# 96 wavelets, each pair at M = 64 costing 1.86 of one at M = 16, `_pair_cost`) took 16.8 CPU ms on one
# thread (prt15), 1.36M pairs of M = 16 a second; 16000 steps took 284-292 s of a default job.
STEP_PAIRS_PER_SECOND = 1_300_000.0
# A pair's cost grows with M (U is M x M, h_k of width M feeds f): 2000 default steps took 52-54 CPU s at
# M = 16 and 96-105 s at M = 64 (prt11, loaded machine), 1.85x: a pair costs 1 + (M - 16) / 56 times
# what it costs at M = 16 (`_pair_cost`). f 128 wide instead of 64 took a step 2.2x the CPU (prt15, one
# thread, default batches of random inputs, 16.8 against 37.1 ms): a power law through the two widths.
BYTES_PER_PARAMETER = 2  # float16 as stored


def parameter_counts(config: PrtConfig) -> dict[str, int]:
    """Parameters of S (hash table), W, U and f."""
    geometry = config.grid.geometry(3)
    table = sum(
        min(geometry.vertices_per_side(level) ** 3, 2**config.grid.log2_table_size)
        for level in range(geometry.n_levels)
    )
    m = config.grid.levels * config.grid.features_per_level
    inputs = m + (config.directions.degree + 1) ** 2 + 10
    widths = [inputs] + [config.mlp.width] * config.mlp.depth + [3]
    f = sum(a * b + b for a, b in itertools.pairwise(widths))
    return {"S": table * config.grid.features_per_level, "W": config.n_wavelets * m, "U": m * m, "f": f}


def plan(scene: SceneRef, config: PrtConfig) -> Plan:
    choices = probe_objects(scene, config)
    box = scene_box(scene, config)
    counts = parameter_counts(config)
    sizes = ", ".join(f"{name} {n * BYTES_PER_PARAMETER / 2**20:.2f} MiB" for name, n in counts.items())
    r = config.cube_size
    row_bytes = 6 * r * r * 3 * 4
    rows = config.cameras.train_views * config.rows_per_view
    targets = (
        "training targets are the rows themselves"
        if config.row_neighbours == 1
        else f"training targets average each row's nearest rows, up to {config.row_neighbours}, as many "
        "as leave-one-out chooses per object"
    )
    items = [
        PlanItem(name=c.name, choice="modelled" if c.modelled else "direct only", reason=c.reason)
        for c in choices
    ]
    items += [
        PlanItem(
            name="lighting",
            choice=f"cube map 6 x {r}^2 ({6 * r * r} Haar wavelets), K = {config.wavelets} per frame",
            reason=f"{config.selection}-weighted selection; training uses {config.train_top_wavelets} "
            f"largest + {config.train_uniform_wavelets} uniform wavelets of a fresh lighting every step",
        ),
        PlanItem(
            name="hash grid box",
            choice=f"{np.round(box[0], 3).tolist()} to {np.round(box[1], 3).tolist()}",
            reason="every surface point a training or test view sees, padded",
        ),
        PlanItem(
            name="memory",
            choice=f"{sum(counts.values()) * BYTES_PER_PARAMETER / 2**20:.2f} MiB as float16",
            reason=f"{sizes}; {config.grid.describe()}, {config.mlp.describe()}",
        ),
        PlanItem(
            name="ground truth",
            choice=f"{rows} transport rows of {row_bytes / 1024:.1f} kB ({rows * row_bytes / 2**20:.0f} MiB"
            ", twice with their targets' Haar coefficients)",
            reason=f"{config.rows_per_view} pixels x {config.cameras.train_views} views at "
            f"{config.row_spp} spp, binned by escape texel: one trace serves every lighting; {targets}",
        ),
        frame_item(config),
    ]
    test_pixels = (config.cameras.near_views + config.cameras.far_views) * config.image_size**2
    lightings = len(config.lighting.test_hdris) + config.lighting.test_procedural
    paths = rows * config.row_spp + 2 * lightings * test_pixels * config.test_spp  # indirect and direct
    pairs = (
        config.train.steps
        * config.pixels_per_step
        * (config.train_top_wavelets + config.train_uniform_wavelets)
    )
    seconds = paths / PATHS_PER_SECOND + pairs * _pair_cost(config) / STEP_PAIRS_PER_SECOND
    frame_spp = config.evaluation_spp or sum(config.frame_spp_choices)  # every count tried is rendered
    view = report_view(config.image_size**2, frame_spp, config.reference_spp, config.max_depth)
    fixed = fixed_costs(scene, config, (view,))
    items.append(fixed.item())
    seconds += fixed.seconds
    modelled = sum(c.modelled for c in choices)
    summary = f"indirect light of {modelled} of {len(choices)} objects under any lighting; {rows} rows"
    return Plan(items=items, estimated_seconds=seconds, summary=summary)


def frame_item(config: PrtConfig) -> PlanItem:
    """The artifact's frame: the config's direct-light spp, or the counts the job will try (`frame_spp`)."""
    shading = "half the pixels (checkerboard)" if config.checkerboard else "every pixel"
    how = f"{'denoised, ' if config.denoise_direct else ''}the network at {shading}"
    if config.evaluation_spp is not None:
        return PlanItem(
            name="frame",
            choice=f"direct light at {config.evaluation_spp} spp",
            reason=f"set by the config; {how}",
        )
    counts = ", ".join(map(str, config.frame_spp_choices))
    return PlanItem(
        name="frame",
        choice=f"direct light at {counts} spp, counted",
        reason="the job keeps the count whose frame of the report's view beats path tracing by most at equal "
        f"cost (rays traced and network FLOPs, not time), by FLIP and by PSNR (`frame_spp`); {how}",
    )


def _pair_cost(config: PrtConfig) -> float:
    """A pixel-wavelet pair's cost relative to M = 16 and f 64 wide (see STEP_PAIRS_PER_SECOND)."""
    m = config.grid.levels * config.grid.features_per_level
    return (1.0 + (m - 16) / 56) * (config.mlp.width / 64) ** math.log2(2.2)
