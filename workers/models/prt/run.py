"""The `prt` method on the shared pipeline: one network per scene, trained on binned transport under a
fresh lighting every step, exported with its box and modelled objects, measured on held-out lightings and
views, and reported against path tracing of a far view under the first held-out lighting."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np
import torch

from workers.models.prt import artifact
from workers.models.prt.config import PrtConfig
from workers.models.prt.data import cameras
from workers.models.prt.evaluate import held_out_cases, summarise
from workers.models.prt.frame import render_frame
from workers.models.prt.lighting import held_out_lightings, lighting_cube, relit_tracer
from workers.models.prt.network import PrtNetwork
from workers.models.prt.plan import parameter_counts
from workers.models.prt.probe import probe_objects
from workers.models.prt.source import PrtSource, PrtSourceConfig, unit_mean
from workers.models.prt.train import prt_loss
from workers.models.prt.views import FAR, NEAR, TRAIN
from workers.render.render import RenderSettings
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.report import TimedImage
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Phase
from workers.runtime.view import PathTracedView


class PrtMethod:
    kind = "prt"

    def trainables(self, ctx: JobContext) -> list[Trainable]:
        config: PrtConfig = ctx.config
        for choice in probe_objects(ctx.scene, config):
            ctx.log(f"{choice.name}: {choice.reason}")
        spec = SourceSpec(PrtSource, PrtSourceConfig(ctx.scene, config), ctx.seed)
        source = spec.build()
        ctx.log(f"{len(source.data.rows)} transport rows traced at {config.row_spp} spp")
        torch.manual_seed(ctx.seed)
        model = PrtNetwork(config)
        phases = [Phase("main", partial(prt_loss, mu=config.mu, transport_weight=config.transport_weight))]
        return [Trainable(model, phases, spec, config.train, stored_dtype=artifact.STORAGE_DTYPE)]

    def finish(self, ctx: JobContext, trained: list[Trained]) -> Finished:
        config: PrtConfig = ctx.config
        (done,) = trained
        model: PrtNetwork = done.model
        source: PrtSource = done.trainable.source.build()
        objects = np.asarray(source.objects, np.int64)
        files = artifact.save(ctx.output_dir, config, model, source.data.box, source.objects, ctx.scene.spec)

        ctx.log("measuring on held-out lightings and views")
        cases = held_out_cases(model, source.data.box, objects, ctx.scene, config, ctx.seed)
        figures = summarise(cases)
        counts = parameter_counts(config)
        method_metrics = {
            **figures,
            **{f"parameters.{name}": float(n) for name, n in counts.items()},
            "rows": float(len(source.data.rows)),
            "modelled_objects": float(len(objects)),
            "wavelets": float(config.wavelets),
        }
        metrics = {k: figures[k] for k in ("psnr_full", "psnr_indirect", "ssim_full", "flip_full")}

        # The report's view: a far (else near, else training) view under the first held-out lighting.
        views = cameras(ctx.scene, config)
        camera = (views[FAR] or views[NEAR] or views[TRAIN])[0]
        name, env = next(iter(held_out_lightings(config.lighting, ctx.seed).items()))
        cube = unit_mean(lighting_cube(env, config.cube_size, config.lighting.map_width))
        compiled = ctx.scene.compiled()
        at_view = replace(compiled, spec=compiled.spec.model_copy(update={"camera": camera}))
        tracer = relit_tracer(at_view, cube)
        settings = RenderSettings(
            spp=config.evaluation_spp, width=camera.width, height=camera.height, max_depth=config.max_depth,
            seed=ctx.seed, threads=1,
        )  # fmt: skip
        view = PathTracedView(at_view, settings, config.reference_spp, tracer=tracer)
        ctx.log(f"report view: {camera.width}x{camera.height}, far view under {name}")
        frame = render_frame(
            model, source.data.box, objects, tracer, cube, camera,
            k=config.wavelets, weighting=config.selection, spp=config.evaluation_spp, seed=ctx.seed,
            denoise=config.denoise_direct,
        )  # fmt: skip
        denoised = " denoised" if config.denoise_direct else ""
        label = f"direct {config.evaluation_spp} spp{denoised} + K={config.wavelets}"
        timed = TimedImage(label, frame.image, frame.seconds)
        method_metrics["report_view.network_seconds"] = frame.network_seconds
        return Finished(files, view, timed, method_metrics, metrics, preview=[frame.direct, frame.indirect])
