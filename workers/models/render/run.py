"""Running a render job: sampler actors render (pass, tile) items, the driver sums them in plan order.

Summing in plan order makes the image bit-identical to `workers.render.render.render` with the same
settings, whichever actor rendered which item, and across a resume from a checkpoint.
"""

from __future__ import annotations

import time

from workers.models.registry import InfrastructureFailure, JobContext, RunOutput
from workers.models.render import checkpoint
from workers.models.render.config import RenderConfig
from workers.models.render.outputs import write_outputs
from workers.models.render.source import TileSource, TileSourceConfig, from_batch
from workers.render.camera import PinholeCamera
from workers.render.render import ImageAccumulator, TileResult, plan_render
from workers.runtime.samplers import BatchStream, InProcessBatches, SamplerPool
from workers.runtime.sources import SourceSpec
from workers.scene.compile import compile_scene


def run(ctx: JobContext) -> RunOutput:
    config: RenderConfig = ctx.config
    settings = config.settings(ctx.seed)
    compile_scene(ctx.scene, ctx.scene_dir)  # scene errors surface here, in one clear line, not in actors
    plan = plan_render(PinholeCamera(ctx.scene.camera, settings.width, settings.height), settings)
    accum = ImageAccumulator(plan, settings.aovs)
    resumed = checkpoint.restore(ctx.checkpoints, settings, accum)
    passes_done = resumed.passes_done if resumed else 0
    seconds_before = resumed.seconds if resumed else 0.0
    if resumed:
        ctx.log(f"resuming from the checkpoint after pass {passes_done} of {len(plan.passes)}")
    ctx.log(
        f"rendering {plan.width}x{plan.height} at {settings.spp} spp: {len(plan.passes)} passes of "
        f"{len(plan.tiles)} tiles on {config.samplers or 'no'} sampler actor(s)"
    )
    scene_dir = None if ctx.scene_dir is None else str(ctx.scene_dir)
    source = TileSourceConfig(scene=ctx.scene.model_dump(mode="json"), scene_dir=scene_dir, settings=settings)
    spec = SourceSpec(TileSource, source, ctx.seed)
    start = last_checkpoint = time.perf_counter()
    pixels = plan.width * plan.height
    samples_before = sum(plan.passes[:passes_done])
    with _open_stream(spec, config, ctx, passes_done * len(plan.tiles)) as stream:
        for pass_index in range(passes_done, len(plan.passes)):
            for tile in plan.tiles:
                ctx.raise_if_cancelled()
                accum.add(tile, _next_item(stream))
            now = time.perf_counter()
            samples_done = sum(plan.passes[: pass_index + 1])
            rate = (samples_done - samples_before) * pixels / max(now - start, 1e-9)
            last = pass_index == len(plan.passes) - 1
            if last or now - last_checkpoint >= config.checkpoint_interval_s:
                state = checkpoint.RenderState(
                    passes_done=pass_index + 1,
                    rays_traced=accum.rays_traced,
                    seconds=seconds_before + now - start,
                    settings=settings,
                )
                checkpoint.save(ctx.checkpoints, state, accum)
                last_checkpoint = time.perf_counter()
            ctx.progress(
                samples_done,
                settings.spp,
                samples_per_s=rate,
                eta_s=(settings.spp - samples_done) * pixels / max(rate, 1e-9),
            )
    seconds = seconds_before + time.perf_counter() - start
    result = accum.result(settings.spp, seconds)
    metrics = {"seconds": seconds, "rays_per_second": result.rays_per_second, "spp": float(settings.spp)}
    report = {
        **metrics,
        "width": plan.width,
        "height": plan.height,
        "rays_traced": result.rays_traced,
        "passes": len(plan.passes),
        "tiles": len(plan.tiles),
        "samplers": config.samplers,
        "seed": ctx.seed,
        "resumed_after_pass": passes_done if resumed else None,
    }
    return RunOutput(files=write_outputs(ctx.output_dir, result, report), metrics=metrics)


def _open_stream(spec: SourceSpec, config: RenderConfig, ctx: JobContext, start: int) -> BatchStream:
    if config.samplers == 0:
        return InProcessBatches(spec, start=start)
    return SamplerPool(spec, actors=config.samplers, actor_options=ctx.sampler_options, start=start)


def _next_item(stream: BatchStream) -> TileResult:
    """The next item in plan order; samplers that keep dying are the cluster's failure, not the job's."""
    replacements = getattr(stream, "replacements", 0)
    try:
        return from_batch(next(stream))
    except RuntimeError as error:
        if getattr(stream, "replacements", 0) > replacements:
            raise InfrastructureFailure(str(error)) from error
        raise
