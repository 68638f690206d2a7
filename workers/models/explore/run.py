"""The `explore` method on the shared pipeline: one network trained on patches the explorer asks the
job's sampler actors for, exported with the scene and measured at fixed configurations.

The report's view is the scene at the middle of every range; `method_metrics` add the mean DSSIM and MAPE
over `evaluation_configurations` fixed configurations against `reference_spp` path tracing, the frame
time and the explorer's figures (acceptance rate, share of generated steps, final R and p_s).
"""

from __future__ import annotations

import torch

from workers.models.explore import artifact
from workers.models.explore.config import ExploreConfig
from workers.models.explore.evaluate import (
    ANTIALIASING,
    configuration_errors,
    configurations,
    network_image,
    reference_images,
)
from workers.models.explore.explorer import Explorer
from workers.models.explore.network import PixelGenerator
from workers.models.explore.source import PatchSource, PatchSourceConfig
from workers.render.render import RenderSettings
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.report import TimedImage
from workers.runtime.sources import SourceSpec
from workers.runtime.view import PathTracedView


class ExploreMethod:
    kind = "explore"

    def __init__(self) -> None:
        self.explorer: Explorer | None = None
        self.source: PatchSource | None = None

    def trainables(self, ctx: JobContext) -> list[Trainable]:
        config: ExploreConfig = ctx.config
        spec = SourceSpec(PatchSource, PatchSourceConfig(ctx.scene, config), ctx.seed)
        self.source = spec.build()
        torch.manual_seed(ctx.seed)
        model = PixelGenerator.of(config, self.source.dimensions)
        self.explorer = Explorer(config, self.source.dimensions, model, ctx.seed)
        phases = [self.explorer.phase()]
        return [
            Trainable(
                model,
                phases,
                spec,
                config.train,
                stored_dtype=artifact.STORAGE_DTYPE,
                driven=self.explorer.open,
            )
        ]

    def finish(self, ctx: JobContext, trained: list[Trained]) -> Finished:
        config: ExploreConfig = ctx.config
        source, model = self.source, self.explorer.average  # the trained weights' average (`Explorer`)
        files = artifact.save(
            ctx.output_dir, config, model, ctx.scene.spec, source.box, ctx.scene.local_folder()
        )
        ctx.raise_if_cancelled()
        vectors = configurations(source.dimensions, config.evaluation_configurations, ctx.seed)
        states = [source.scene.at(v) for v in vectors]
        tracers = [source.tracer.state_tracer(s) for s in states]
        size = config.preview_size
        view = PathTracedView(
            states[0].compiled,
            RenderSettings(
                spp=config.evaluation_spp, width=size, height=size, max_depth=config.max_depth, seed=ctx.seed,
                threads=1,
            ),
            config.reference_spp,
            tracer=tracers[0],
        )  # fmt: skip
        ctx.log(f"measuring the network at {len(vectors)} configurations against {config.reference_spp} spp")
        others = reference_images(tracers[1:], size, config.reference_spp, config.max_depth, ctx.seed + 2)
        references = [view.reference(), *others]
        errors = configuration_errors(model, tracers, vectors, references, source.box)
        camera = states[0].compiled.spec.camera
        image, seconds = network_image(  # timed as the errors are measured: antialiased
            model, tracers[0], camera, source.box, vectors[0], size, size, ANTIALIASING
        )
        statistics = self.explorer.statistics()
        means = errors.means()
        method_metrics = {
            **{f"configurations.{k}": v for k, v in means.items()},
            **{f"configuration_{i}.dssim": d for i, d in enumerate(errors.dssim)},
            "frame_ms": seconds * 1e3,
            "dimensions": float(source.dimensions),
            **{f"exploration.{k}": v for k, v in statistics.items()},
        }
        metrics = {
            "dssim": means["dssim"],
            "mape": means["mape"],
            "acceptance_rate": statistics["acceptance_rate"],
        }
        frame = TimedImage("network", image, seconds)
        return Finished(files, view, frame, method_metrics, metrics)
