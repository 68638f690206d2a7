"""The `lod` kind: neural prefiltering for correlation-aware levels of detail (Weier et al. 2023).

An asset becomes a sparse multi-level voxel grid (`grid`) with two networks (`networks`): appearance
(average throughput per voxel) and visibility (segment occlusion), trained on path-traced samples drawn on
the fly (`sampling`, `train`); per-voxel thresholds (`thresholds`) make visibility correlation-aware; the
path tracer renders any LoD through `traversal`. `plan` picks objects and LoDs, `artifact` stores and
loads, `evaluate` measures.
"""

from __future__ import annotations

from workers.models.lod.config import PRESETS, LodConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="lod",
    config_model=LodConfig,
    presets=PRESETS,
    plan_function="workers.models.lod.plan:plan",
    example=Example("menger_sponge", {"samplers": 0}),
    method="workers.models.lod.run:LodMethod",
    infer_module="workers.models.lod.infer",
)
