"""The `render` kind: a reference path-traced image (EXR, G-buffers, PNG preview) run as a job."""

from __future__ import annotations

from workers.models.render.config import PRESETS, RenderConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="render",
    config_model=RenderConfig,
    presets=PRESETS,
    plan_function="workers.models.render.plan:plan",
    example=Example("cornell_box", {"samplers": 0}),
    run_function="workers.models.render.run:run",
    infer_module="workers.models.render.infer",
)
