"""The `explore` kind: a neural renderer for variable scenes trained by active exploration (Diolatzis,
Philip and Drettakis 2022; thesis Ch. 5, App. A).

A scene with K variables (`SceneSpec.variables`) becomes one network that maps per-pixel G-buffers and the
scene vector v to the radiance leaving the first hit (`network`, `features`). Training patches are crops
of path-traced R x R images (`source`) chosen by Markov chains that seek where the loss times Adam's step
is largest (`exploration`, `oracle`, `explorer`), reused while new ones would teach no more (`reuse`), at a
growing resolution (`config.resolution`). `plan` reports the variables, `artifact` stores the network with
its scene, `evaluate` measures it and `infer` serves it.
"""

from __future__ import annotations

from workers.models.explore.config import PRESETS, ExploreConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="explore",
    config_model=ExploreConfig,
    presets=PRESETS,
    plan_function="workers.models.explore.plan:plan",
    example=Example("cornell_moving_light"),
    method="workers.models.explore.run:ExploreMethod",
    infer_module="workers.models.explore.infer",
)
