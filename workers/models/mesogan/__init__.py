"""The `mesogan` kind: a generative neural mesoscale material (fur, grass, carpet) rendered on meshes
through shell mapping (Diolatzis 2022, Ch. 6; published as MesoGAN, EGSR 2023).

`sampling` path-traces labelled views of random procedural slabs (`workers.scene.generators.mesoscale`);
`networks` holds the infinite plane generator, the decoder and the discriminator, `slab` renders the
generated slab as training does, `train` the GAN's phases; `shell` is the prism map, `aggregate` the
material inside our path tracer, `covering` lays the plane over a scene's surfaces, `material` is the
`mesogan` material scene files name; `plan`, `run`, `artifact` and `infer` are the kind's parts.
"""

from __future__ import annotations

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="mesogan",
    config_model=MesoganConfig,
    presets=PRESETS,
    plan_function="workers.models.mesogan.plan:plan",
    example=Example("fur_ball"),
    method="workers.models.mesogan.run:MesoganMethod",
    infer_module="workers.models.mesogan.infer",
    materials={"mesogan": "workers.models.mesogan.material:draw"},
)
