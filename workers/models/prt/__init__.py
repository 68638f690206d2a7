"""The `prt` kind: neural-wavelet precomputed radiance transfer for glossy indirect light from any
viewpoint under any environment map (Raghavan, Xiao et al., EGSR 2023).

Lighting is a cube map in the Haar basis (`workers.nn.haar`, `workers.nn.cubemap`, `lighting`); the
network (`network`) predicts each wavelet's transport at a pixel, B = sum_k L_k T_k over the K wavelets a
frame selects (`selection`, `frame`), and direct light is path-traced. Ground truth is binned transport
(`transport`): one trace per pixel serves every lighting (`data`, `source`, `train`); `probe` and `plan`
say what is modelled, `evaluate` measures held-out lightings and views, `artifact` and `infer` serve it.
"""

from __future__ import annotations

from workers.models.prt.config import PRESETS, PrtConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="prt",
    config_model=PrtConfig,
    presets=PRESETS,
    plan_function="workers.models.prt.plan:plan",
    example=Example("env_lit_objects"),
    method="workers.models.prt.run:PrtMethod",
    infer_module="workers.models.prt.infer",
)
