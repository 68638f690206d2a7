"""The `lsnif` kind: neural intersection functions that replace per-object BVHs (Fujieda et al. 2025).

Per object in local space: surface voxels (`workers.render.voxels`), a sparse grid on the occupied
voxels (`encoding`), one MLP (`network`), trained on view-independent rays labelled by Embree
(`sampling`, `train`); `plan` picks the objects, `artifact` stores and loads them and builds the path
tracer's intersector, `evaluate` measures them.
"""

from __future__ import annotations

from pydantic import BaseModel

from workers.models.lsnif.config import PRESETS, LsnifConfig
from workers.models.registry import JobContext, Plan, Resources, RunOutput, resolve_preset
from workers.scene.spec import SceneSpec


class LsnifKind:
    name = "lsnif"
    config_model = LsnifConfig
    presets = PRESETS
    infer_module = "workers.models.lsnif.infer"

    def resolve_config(self, preset: str, overrides: dict) -> LsnifConfig:
        return resolve_preset(LsnifConfig, PRESETS, preset, overrides)

    def plan(self, scene: SceneSpec, config: BaseModel) -> Plan:
        from workers.models.lsnif.plan import plan

        return plan(scene, config)

    def resources(self, config: LsnifConfig) -> Resources:
        return Resources(num_cpus=1, num_gpus=config.num_gpus)

    def run(self, ctx: JobContext) -> RunOutput:
        from workers.models.lsnif.run import run  # torch and the path tracer load only where jobs run

        return run(ctx)


KIND = LsnifKind()
