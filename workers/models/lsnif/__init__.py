"""The `lsnif` kind: neural intersection functions that replace per-object BVHs (Fujieda et al. 2025).

Per object in local space: surface voxels (`workers.render.voxels`), a sparse grid on the occupied
voxels (`encoding`), one MLP (`network`), trained on view-independent rays labelled by Embree
(`sampling`, `train`); `plan` picks the objects, `artifact` stores and loads them and builds the path
tracer's intersector, `evaluate` measures them.
"""

from __future__ import annotations

from workers.models.lsnif.config import PRESETS, LsnifConfig
from workers.runtime.contract import Example, Kind

KIND = Kind(
    name="lsnif",
    config_model=LsnifConfig,
    presets=PRESETS,
    plan_function="workers.models.lsnif.plan:plan",
    example=Example("thin_walls"),
    method="workers.models.lsnif.run:LsnifMethod",
    infer_module="workers.models.lsnif.infer",
)
