"""What a render costs before it runs: image size, passes, tiles and a time estimate from a ray budget."""

from __future__ import annotations

from workers.models.render.config import RenderConfig
from workers.render.camera import PinholeCamera
from workers.render.render import MAX_PATHS_PER_ITEM, plan_render
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import fixed_costs
from workers.scene.format.spec import AggregateMaterial
from workers.scene.portability.reference import SceneRef

RAYS_PER_SECOND_PER_CORE = 2.5e6  # Embree closest hits plus NumPy shading, measured on the build machines
RAYS_PER_SAMPLE = 8  # camera ray, bounces and shadow rays of an average path at max_depth 8


def plan(scene: SceneRef, config: RenderConfig) -> Plan:
    settings = config.settings(seed=0)
    render_plan = plan_render(PinholeCamera(scene.spec.camera, settings.width, settings.height), settings)
    cores = max(config.samplers, 1)
    rays_per_sample = RAYS_PER_SAMPLE + (1 if config.aovs else 0)
    rays = config.width * config.height * config.spp * rays_per_sample
    seconds = rays / (RAYS_PER_SECOND_PER_CORE * cores)
    passes, tiles = len(render_plan.passes), len(render_plan.tiles)
    items = [
        PlanItem(
            name="image",
            choice=f"{config.width}x{config.height} at {config.spp} spp",
            reason="the config's size and sample count; the scene camera supplies the view",
        ),
        PlanItem(
            name="passes",
            choice=f"{passes} pass(es) of up to {render_plan.passes[0]} spp",
            reason=f"one (pass, tile) item traces at most {MAX_PATHS_PER_ITEM} paths to bound memory; "
            "progress and checkpoints come after each pass",
        ),
        PlanItem(
            name="tiles",
            choice=f"{tiles} tile(s) of {config.tile_size} px",
            reason="tiles are the unit of parallel work: each has its own seeded random stream",
        ),
        PlanItem(
            name="samplers",
            choice=f"{config.samplers} Ray sampler actor(s)" if config.samplers else "in the driver",
            reason="each actor compiles the scene once and renders items on one core",
        ),
        PlanItem(
            name="estimate",
            choice=f"{seconds:.1f} s",
            reason=f"{rays_per_sample} rays per sample at {RAYS_PER_SECOND_PER_CORE:.1e} rays/s per core "
            f"on {cores} core(s); scenes with long paths or many lights take longer",
        ),
    ]
    materials = scene.spec.materials
    drawn = sorted(
        {o.material for o in scene.spec.objects if isinstance(materials[o.material], AggregateMaterial)}
    )
    if drawn:
        items.append(
            PlanItem(
                name="aggregate materials",
                choice=", ".join(f"{name} ({materials[name].type})" for name in drawn),
                reason="drawn as a volume over their surfaces by the kind that registers the type; every "
                "process that renders (the driver or each actor) loads its model once",
            )
        )
    fixed = fixed_costs(scene, config)
    items.append(fixed.item())
    summary = f"render {config.width}x{config.height} at {config.spp} spp in {passes * tiles} items"
    return Plan(items=items, estimated_seconds=seconds + fixed.seconds, summary=summary)
