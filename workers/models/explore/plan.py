"""What a variable scene needs from `explore`: its variables and dimensions, what stays static, which
variables change what the camera sees, the sizes for the preset and the estimated cost.

A variable "changes the view" when the camera sees a difference between the scene at its two ends (the
others at the middle): the 16 x 16 G-buffers differ, or 4-spp renders with the same seed differ by more
than `SEEN_DIFFERENCE` of their mean (paths that never meet what the variable changes trace the same
random numbers). A variable that moves an object the camera never sees, or lights nothing it sees, is
reported as such.
"""

from __future__ import annotations

import numpy as np

from workers.models.explore.config import ExploreConfig
from workers.models.explore.reuse import reuse_probability
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import is_mirror, primary_gbuffers
from workers.render.render import RenderSettings, render
from workers.render.variable_tracer import VariableTracer
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import Evaluation, fixed_costs, report_view
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import RoughnessVariable, SceneSpec
from workers.scene.format.variables import dimension_labels, variable_slices
from workers.scene.geometry.variable_scene import CompiledVariableScene
from workers.scene.portability.reference import SceneRef

PROBE_SIZE = 16
PROBE_SPP = 4
SEEN_DIFFERENCE = 0.02  # relative mean absolute difference of the probe renders
# CPU costs on this 2-core machine, one thread (explore27): a `default` patch (16^2 at 32 spp, depth 5)
# rendered in 18 ms on cornell_variable, 15 ms on mirror_variable, a `quick` one (8^2 at 8 spp, depth 3)
# in 4-7 ms, so about 6 ms a patch (G-buffers, the scene at v) plus 3e-7 s a path segment; an Adam step
# of the default 128 x 4 network on 12 patches of 16^2 took 31 ms, 2e-6 s a pixel and layer of width
# 128, the quick 32 x 2 on 6 of 8^2 1 ms, while a quick job's 1000 steps took 3.6 s in all: the explorer's
# own work is most of a small step (SECONDS_PER_STEP rounds it up to 5 ms). (Until explore27 the
# constants were 1.4e-5 s a segment, no per-patch cost and 2e-8 s a pixel-layer: errors that cancelled
# while p_s was 0.99.)
SECONDS_PER_PATCH = 6e-3
SECONDS_PER_PATH_SEGMENT = 3e-7
SECONDS_PER_STEP = 0.005
SECONDS_PER_PIXEL_LAYER = 2e-6  # per pixel, per layer of width 128, forward and backward


def visible_effect(tracer: VariableTracer, scene: CompiledVariableScene, name: str, where: slice) -> bool:
    """Whether the camera sees a change between the variable at 0 and at 1 (others at the middle)."""
    buffers_at, images = [], []
    for end in (0.0, 1.0):
        v = np.full(scene.dimensions, 0.5)
        v[where] = end
        state = scene.at(v)
        path_tracer = tracer.state_tracer(state)
        camera = state.compiled.spec.camera
        buffers = primary_gbuffers(path_tracer, PinholeCamera(camera, PROBE_SIZE, PROBE_SIZE))
        settings = RenderSettings(
            spp=PROBE_SPP, width=PROBE_SIZE, height=PROBE_SIZE, max_depth=3, seed=0, threads=1
        )
        images.append(render(path_tracer, settings).image)
        buffers_at.append(
            np.concatenate([buffers.position, buffers.albedo, buffers.roughness, buffers.emission], -1)
        )
    if not np.allclose(buffers_at[0], buffers_at[1], atol=1e-5):
        return True
    difference = np.abs(images[0] - images[1]).mean()
    return bool(difference > SEEN_DIFFERENCE * max(0.5 * (images[0].mean() + images[1].mean()), 1e-12))


def mirror_objects(spec: SceneSpec) -> list[str]:
    """The objects whose material is a mirror (`gbuffer.is_mirror`) as given or at the smooth end of a
    roughness variable (cornell_variable's sphere below roughness 0.05)."""
    smoothest = {}
    for variable in spec.variables:
        if isinstance(variable, RoughnessVariable):
            smoothest[variable.material] = min(variable.min, variable.max)
    materials = {
        name: m.model_copy(update={"roughness": smoothest[name]}) if name in smoothest else m
        for name, m in spec.materials.items()
    }
    return [o.name for o in spec.objects if is_mirror(materials[o.material])]


def plan(scene: SceneRef, config: ExploreConfig) -> Plan:
    spec = scene.spec
    if not spec.variables:
        raise SceneError(
            "variables", "explore trains a renderer for a variable scene: name at least one variable"
        )
    compiled = CompiledVariableScene(spec, scene.local_folder())
    tracer = VariableTracer(compiled)
    slices = variable_slices(spec)
    items = []
    for variable in spec.variables:
        labels = dimension_labels(variable)
        seen = visible_effect(tracer, compiled, variable.name, slices[variable.name])
        reason = f"{len(labels)} dimension(s): {', '.join(labels)}"
        if not seen:
            reason += "; the camera sees no change over its range (it moves or lights nothing in view)"
        items.append(PlanItem(name=variable.name, choice=variable.type if seen else "unseen", reason=reason))
    static = [
        compiled.base.objects[i].name for i in range(len(compiled.base.objects)) if i not in compiled.moved
    ]
    items.append(
        PlanItem(
            name="static",
            choice=f"{len(compiled.static_triangles)} triangles in one BVH",
            reason=f"no variable moves {', '.join(static)}",
        )
    )
    mirrors = mirror_objects(spec)
    if mirrors:
        items.append(
            PlanItem(
                name="mirrors",
                choice=f"followed into the G-buffers, up to {config.mirror_bounces} bounce(s)"
                if config.mirror_bounces
                else "learned by the network",
                reason=f"{', '.join(mirrors)}: near-smooth conductors; mirror_bounces traces what they show "
                "(thesis Fig. 5.10) instead of learning the reflection",
            )
        )
    schedule = (
        f"R {config.resolution_start} -> {config.resolution_max} by {config.resolution_step} every "
        f"{config.resolution_every} iterations"
        if config.schedules_resolution
        else f"R {config.resolution_start} fixed"
    )
    items.append(
        PlanItem(
            name="exploration",
            choice=f"{config.exploration}: {config.chains} chains of {config.patch}^2 patches",
            reason=f"{schedule}; {config.spp} spp, depth {config.max_depth}; "
            f"p_LS {config.large_step_probability}, beta {config.reuse_beta}, bootstrap {config.bootstrap}",
        )
    )
    grid = config.position_grid
    encoding = "" if grid is None else f"; position: {grid.describe()}"
    items.append(
        PlanItem(
            name="network",
            choice=config.mlp.describe() + encoding,
            reason="position preconditioning, skips; the grid stores what v does not change",
        )
    )
    patches = config.chains * config.patch**2
    render_seconds = (
        config.chains * SECONDS_PER_PATCH + patches * config.spp * config.max_depth * SECONDS_PER_PATH_SEGMENT
    )
    # a generation renders the chains' patches and evaluates f on two patches per chain; reuse is one
    # step, with probability p_s after the bootstrap (Eq. 5.4; taken at equal losses)
    generated = 1 - reuse_probability(0.0, 0.0, config.reuse_beta)
    generation_share = min(generated + config.bootstrap / max(config.train.steps, 1), 1.0)
    network = SECONDS_PER_PIXEL_LAYER * patches * (config.mlp.depth + 1) * config.mlp.width / 128
    step = SECONDS_PER_STEP + network
    seconds = config.train.steps * (generation_share * (render_seconds + 2 * network) + step)
    if config.uniform_baseline:
        items.append(
            PlanItem(
                name="baseline",
                choice="uniform sampling at equal wall-clock time",
                reason="the same network, store and start; compared at the configurations in the report",
            )
        )
        seconds *= 2
    pixels, others = config.preview_size**2, config.evaluation_configurations - 1
    view = report_view(pixels, config.evaluation_spp, config.reference_spp, config.max_depth)
    # the other configurations' references, which the network is measured against too
    references = Evaluation(pixels, others * config.reference_spp, config.max_depth, others)
    fixed = fixed_costs(scene, config, (view, references))
    items.append(fixed.item())
    seconds += fixed.seconds
    summary = (
        f"{spec.dimensions} dimension(s), {len(spec.variables)} variable(s); {config.exploration} exploration"
    )
    return Plan(items=items, estimated_seconds=float(seconds), summary=summary)
