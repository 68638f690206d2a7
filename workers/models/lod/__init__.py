"""The `lod` kind: neural prefiltering for correlation-aware levels of detail (Weier et al. 2023).

An asset becomes a sparse multi-level voxel grid (`grid`) with two networks (`networks`): appearance
(average throughput per voxel) and visibility (segment occlusion), trained on path-traced samples drawn on
the fly (`sampling`, `train`); per-voxel thresholds (`thresholds`) make visibility correlation-aware; the
path tracer renders any LoD through `traversal`. `plan` picks objects and LoDs, `artifact` stores and
loads, `evaluate` measures.
"""

from __future__ import annotations

from pydantic import BaseModel

from workers.models.lod.config import PRESETS, LodConfig
from workers.models.registry import JobContext, Plan, Resources, RunOutput, resolve_preset
from workers.scene.spec import SceneSpec


class LodKind:
    name = "lod"
    config_model = LodConfig
    presets = PRESETS
    infer_module = "workers.models.lod.infer"

    def resolve_config(self, preset: str, overrides: dict) -> LodConfig:
        return resolve_preset(LodConfig, PRESETS, preset, overrides)

    def plan(self, scene: SceneSpec, config: BaseModel) -> Plan:
        from workers.models.lod.plan import plan

        return plan(scene, config)

    def resources(self, config: LodConfig) -> Resources:
        return Resources(num_cpus=1, num_gpus=config.num_gpus)

    def run(self, ctx: JobContext) -> RunOutput:
        from workers.models.lod.run import run  # torch and the path tracer load only where jobs run

        return run(ctx)


KIND = LodKind()
