"""Running a render job: sampler actors render (pass, tile) items, the driver sums them in plan order.

Summing in plan order makes the image bit-identical to `workers.render.render.render` with the same
settings, whichever actor rendered which item, and across a resume from a checkpoint.
"""

from __future__ import annotations

import time

from workers.models.render import checkpoint
from workers.models.render.config import RenderConfig
from workers.models.render.outputs import write_outputs
from workers.models.render.source import TileSource, TileSourceConfig, from_batch
from workers.render.camera import PinholeCamera
from workers.render.render import ImageAccumulator, RenderPlan, RenderSettings, plan_render
from workers.runtime.contract import JobContext, RunOutput, SamplerSlots
from workers.runtime.samplers import BatchStream, open_batches
from workers.runtime.sources import SourceSpec


def run(ctx: JobContext[RenderConfig]) -> RunOutput:
    config = ctx.config
    settings = config.settings(ctx.seed)
    ctx.scene.compiled()  # scene errors surface here, in one clear line, not in actors
    plan = plan_render(PinholeCamera(ctx.scene.spec.camera, settings.width, settings.height), settings)
    accum = ImageAccumulator(plan, settings.aovs)
    state = checkpoint.restore(ctx.checkpoints, settings, accum)
    if state is not None:
        ctx.log(f"resuming from the checkpoint after pass {state.passes_done} of {len(plan.passes)}")
    resumed_after = state.passes_done if state else None
    state = state or checkpoint.RenderState(passes_done=0, rays_traced=0, seconds=0.0, settings=settings)
    samplers = 0
    if state.passes_done < len(plan.passes):
        with ctx.reserve_samplers(config.samplers) as slots:
            samplers = slots.count
            ctx.log(
                f"rendering {plan.width}x{plan.height} at {settings.spp} spp: {len(plan.passes)} passes of "
                f"{len(plan.tiles)} tiles on {samplers or 'no'} sampler actor(s)"
            )
            with _open_stream(ctx, settings, slots, state.passes_done * len(plan.tiles)) as stream:
                state = _render_passes(ctx, config, plan, accum, stream, state)
    result = accum.result(settings.spp, state.seconds)
    metrics = {"seconds": state.seconds, "rays_per_second": result.rays_per_second}
    metrics["spp"] = float(settings.spp)
    report = {
        **metrics,
        "width": plan.width,
        "height": plan.height,
        "rays_traced": result.rays_traced,
        "passes": len(plan.passes),
        "tiles": len(plan.tiles),
        "samplers": samplers,
        "seed": ctx.seed,
        "resumed_after_pass": resumed_after,
    }
    return RunOutput(files=write_outputs(ctx.output_dir, result, report), metrics=metrics)


def _render_passes(
    ctx: JobContext[RenderConfig],
    config: RenderConfig,
    plan: RenderPlan,
    accum: ImageAccumulator,
    stream: BatchStream,
    state: checkpoint.RenderState,
) -> checkpoint.RenderState:
    """Add the remaining passes in plan order; progress after each, a checkpoint when one is due."""
    spp = sum(plan.passes)
    pixels = plan.width * plan.height
    run_start = start = last_checkpoint = time.perf_counter()
    samples_before = sum(plan.passes[: state.passes_done])
    for pass_index in range(state.passes_done, len(plan.passes)):
        for tile in plan.tiles:
            ctx.raise_if_cancelled()
            accum.add(tile, from_batch(next(stream)))
        now = time.perf_counter()
        state = state.model_copy(
            update={
                "passes_done": pass_index + 1,
                "rays_traced": accum.rays_traced,
                "seconds": state.seconds + now - start,
            }
        )
        start = now
        if state.passes_done == len(plan.passes) or now - last_checkpoint >= config.checkpoint_interval_s:
            checkpoint.save(ctx.checkpoints, state, accum)
            last_checkpoint = time.perf_counter()
        samples_done = sum(plan.passes[: state.passes_done])
        rate = (samples_done - samples_before) * pixels / max(now - run_start, 1e-9)
        eta = (spp - samples_done) * pixels / max(rate, 1e-9)
        ctx.progress(samples_done, spp, samples_per_s=rate, eta_s=eta)
    return state


def _open_stream(
    ctx: JobContext[RenderConfig], settings: RenderSettings, slots: SamplerSlots, start: int
) -> BatchStream:
    """Items from `start` on, rendered by the reserved sampler actors, or in the driver without any."""
    source = TileSourceConfig(scene=ctx.scene, settings=settings)
    spec = SourceSpec(TileSource, source, ctx.seed)
    return open_batches(spec, slots.count, placement=slots.actor_options, start=start)
