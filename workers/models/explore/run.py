"""The `explore` method on the shared pipeline: one network trained on patches the explorer asks the
job's sampler actors for, exported with the scene and measured at fixed configurations.

The report's view is the scene at the middle of every range; `method_metrics` add the mean DSSIM and MAPE
over `evaluation_configurations` fixed configurations against `reference_spp` path tracing, the frame
time and the explorer's figures (acceptance rate, share of generated steps, final R and p_s). With
`uniform_baseline` the job also trains the uniform baseline at equal wall-clock time (`baseline`) and the
report gives its errors, steps and time beside active exploration's, and their ratios.
"""

from __future__ import annotations

import math

import torch

from workers.models.explore import artifact, baseline
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
        self.baseline: Explorer | None = None
        self.source: PatchSource | None = None

    def trainables(self, ctx: JobContext[ExploreConfig]) -> list[Trainable]:
        config = ctx.config
        spec = SourceSpec(PatchSource, PatchSourceConfig(ctx.scene, config), ctx.seed)
        self.source = spec.build()
        self.explorer = self._explorer(config, ctx.seed)
        trainables = [self._trainable(self.explorer, spec)]
        if config.uniform_baseline:
            self.baseline = self._explorer(baseline.uniform_config(config), ctx.seed)
            active, steps = self.explorer, config.train.steps
            trainables.append(
                self._trainable(
                    self.baseline,
                    spec,
                    name=baseline.NAME,
                    baseline_steps=lambda _: baseline.equal_time_steps(steps, active.counts),
                )
            )
        return trainables

    def _explorer(self, config: ExploreConfig, seed: int) -> Explorer:
        """An explorer of a new network, initialised from the seed (the same weights for the baseline)."""
        torch.manual_seed(seed)
        model = PixelGenerator.of(config, self.source.dimensions)
        return Explorer(config, self.source.dimensions, model, seed)

    @staticmethod
    def _trainable(explorer: Explorer, spec: SourceSpec, **options) -> Trainable:
        return Trainable(
            explorer.model,
            [explorer.phase()],
            spec,
            explorer.config.train,
            stored_dtype=artifact.STORAGE_DTYPE,
            driven=explorer.open,
            **options,
        )

    def finish(self, ctx: JobContext[ExploreConfig], trained: list[Trained]) -> Finished:
        config = ctx.config
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
        bounces = config.mirror_bounces
        errors = configuration_errors(model, tracers, vectors, references, source.box, bounces)
        camera = states[0].compiled.spec.camera
        image, seconds = network_image(  # timed as the errors are measured: antialiased
            model, tracers[0], camera, source.box, vectors[0], size, size, ANTIALIASING, bounces
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
        if self.baseline is not None:
            ctx.log("measuring the uniform baseline at the same configurations")
            uniform = configuration_errors(
                self.baseline.average, tracers, vectors, references, source.box, bounces
            )
            compared = self._compared(trained, means, uniform.means())
            method_metrics.update(compared)
            metrics.update({f"{k}_over_uniform": compared[f"active_over_uniform.{k}"] for k in means})
        frame = TimedImage("network", image, seconds)
        return Finished(files, view, frame, method_metrics, metrics)

    def _compared(self, trained: list[Trained], active: dict, uniform: dict) -> dict[str, float]:
        """The baseline's errors, steps and wall-clock time beside active exploration's, and the ratios."""
        runs = {"active": (trained[0], self.explorer), "uniform": (trained[1], self.baseline)}
        figures = {
            f"{name}.{k}": v
            for name, (run, explorer) in runs.items()
            for k, v in (("steps", float(run.trainable.train.steps)), ("seconds", explorer.counts["seconds"]))
        }
        figures |= {f"uniform.{k}": v for k, v in uniform.items()}
        ratios = {
            f"active_over_uniform.{k}": active[k] / uniform[k] if uniform[k] > 0 else math.nan for k in active
        }
        return figures | ratios
