"""What a scene needs from LSNIF: which objects get a network, which stay on Embree, and why.

An object gets a network when it has at least `min_triangles` triangles (below that a BVH is small and
fast, Sec. 4) and emits no light (light sampling needs its triangles). An instanced object is trained
once, in its local space, and shared by all its instances.
"""

from __future__ import annotations

from dataclasses import dataclass

from workers.models.lsnif.config import LsnifConfig
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import fixed_costs, report_view
from workers.scene.portability.reference import SceneRef

LSNIF = "lsnif"
EMBREE = "embree"
TRAINING_RAYS_PER_SECOND = 50_000.0  # rays drawn per second, one idle 2-core CPU, default sizes
SECONDS_PER_MILLION_TRIANGLES = 6.0  # voxelising and building the object's reference BVH


@dataclass(frozen=True)
class ObjectChoice:
    index: int
    name: str
    choice: str  # LSNIF or EMBREE
    triangles: int
    instances: int
    reason: str


def choose_objects(scene: SceneRef, config: LsnifConfig) -> list[ObjectChoice]:
    """Every object's choice, from triangles counted without building the scene (mesh files are read)."""
    choices = []
    for index, (obj, triangles) in enumerate(zip(scene.spec.objects, scene.object_triangles(), strict=True)):
        instances = len(obj.instances or [None])
        if obj.emission is not None:
            choice, reason = EMBREE, "emits light: light sampling needs its triangles"
        elif triangles < config.min_triangles:
            choice, reason = EMBREE, f"{triangles} triangles < {config.min_triangles}: a BVH is cheaper"
        else:
            shared = f", shared by its {instances} instances" if instances > 1 else ""
            choice, reason = LSNIF, f"{triangles} triangles >= {config.min_triangles}: trained once{shared}"
        choices.append(ObjectChoice(index, obj.name, choice, triangles, instances, reason))
    return choices


def plan(scene: SceneRef, config: LsnifConfig) -> Plan:
    choices = choose_objects(scene, config)
    trained = [c for c in choices if c.choice == LSNIF]
    rays = config.train.steps * config.batch_size
    seconds = sum(
        rays / TRAINING_RAYS_PER_SECOND + SECONDS_PER_MILLION_TRIANGLES * c.triangles / 1e6 for c in trained
    )
    items = [PlanItem(name=c.name, choice=c.choice, reason=c.reason) for c in choices]
    items.append(
        PlanItem(
            name="training",
            choice=f"{config.train.steps} steps of {config.batch_size} rays per network",
            reason=f"V={config.voxel_resolution}, H={config.max_points}, sparse {config.grid.describe()}, "
            f"{config.mlp.describe()}",
        )
    )
    instances = sum(c.instances for c in trained)
    on_embree = len(choices) - len(trained)
    fixed = fixed_costs(
        scene, config, (report_view(config.preview_size**2, config.evaluation_spp, config.reference_spp),)
    )
    items.append(fixed.item())
    summary = f"{len(trained)} network(s) for {instances} instance(s); {on_embree} object(s) on Embree"
    return Plan(items=items, estimated_seconds=seconds + fixed.seconds, summary=summary)
