"""The `render` kind: a reference path-traced image (EXR, G-buffers, PNG preview) run as a job."""

from __future__ import annotations

from pydantic import BaseModel

from workers.models.registry import JobContext, Plan, Resources, RunOutput, resolve_preset
from workers.models.render import plan as planning
from workers.models.render.config import PRESETS, RenderConfig
from workers.scene.spec import SceneSpec


class RenderKind:
    name = "render"
    config_model = RenderConfig
    presets = PRESETS
    infer_module = "workers.models.render.infer"

    def resolve_config(self, preset: str, overrides: dict) -> RenderConfig:
        return resolve_preset(RenderConfig, PRESETS, preset, overrides)

    def plan(self, scene: SceneSpec, config: BaseModel) -> Plan:
        return planning.plan(scene, config)

    def resources(self, config: RenderConfig) -> Resources:
        return Resources(num_cpus=max(config.samplers, 1), num_gpus=config.num_gpus)

    def run(self, ctx: JobContext) -> RunOutput:
        from workers.models.render.run import run  # the path tracer loads only where jobs run

        return run(ctx)


KIND = RenderKind()
