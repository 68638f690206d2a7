"""The `prt` method on the shared pipeline: one network per scene, trained on binned transport under a
fresh lighting every step, exported with its box and modelled objects, measured on held-out lightings and
views, and reported against path tracing of a far view under the first held-out lighting."""

from __future__ import annotations

from functools import partial

import numpy as np
import torch

from workers.models.prt import artifact
from workers.models.prt.config import PrtConfig
from workers.models.prt.evaluate import ReportView, held_out_cases, report_view, summarise
from workers.models.prt.frame import Frame
from workers.models.prt.frame_spp import best, frame_candidates, timed
from workers.models.prt.network import PrtNetwork
from workers.models.prt.plan import parameter_counts
from workers.models.prt.probe import probe_objects
from workers.models.prt.source import PrtSource, PrtSourceConfig
from workers.models.prt.train import prt_loss
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.report import TimedImage
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Phase


class PrtMethod:
    kind = "prt"

    def trainables(self, ctx: JobContext[PrtConfig]) -> list[Trainable]:
        config = ctx.config
        for choice in probe_objects(ctx.scene, config):
            ctx.log(f"{choice.name}: {choice.reason}")
        spec = SourceSpec(PrtSource, PrtSourceConfig(ctx.scene, config), ctx.seed)
        source = spec.build()
        ctx.log(f"{len(source.data.rows)} transport rows traced at {config.row_spp} spp")
        names = [o.name for o in ctx.scene.spec.objects]
        targets = (f"{names[o]} {k} (w_r weight {w:g})" for o, (k, w) in source.data.smoothing.items())
        ctx.log(f"training targets, rows averaged (leave-one-out): {', '.join(targets)}")
        torch.manual_seed(ctx.seed)
        model = PrtNetwork(config)
        phases = [Phase("main", partial(prt_loss, mu=config.mu, transport_weight=config.transport_weight))]
        return [Trainable(model, phases, spec, config.train, stored_dtype=artifact.STORAGE_DTYPE)]

    def finish(self, ctx: JobContext[PrtConfig], trained: list[Trained]) -> Finished:
        config = ctx.config
        (done,) = trained
        model: PrtNetwork = done.model
        source: PrtSource = done.trainable.source.build()
        objects = np.asarray(source.objects, np.int64)
        box = source.data.box

        ctx.log("measuring on held-out lightings and views")
        cases = held_out_cases(model, box, objects, ctx.scene, config, ctx.seed)
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

        report = report_view(ctx.scene, config, ctx.seed)
        camera = report.camera
        ctx.log(f"report view: {camera.width}x{camera.height}, far view under {report.lighting}")
        frame, seconds, config = self._chosen_frame(ctx, model, box, objects, report, method_metrics)
        files = artifact.save(
            ctx.output_dir, config, model, box, source.objects, ctx.scene.spec, ctx.scene.local_folder()
        )
        denoised = " denoised" if config.denoise_direct else ""
        shading = " checkerboard" if config.checkerboard else ""
        label = f"direct {config.evaluation_spp} spp{denoised} + K={config.wavelets}{shading}"
        timed = TimedImage(label, frame.image, seconds)
        method_metrics["report_view.network_seconds"] = frame.network_seconds
        method_metrics["frame_spp"] = float(config.evaluation_spp)
        preview = [frame.direct, frame.indirect]
        return Finished(files, report.view, timed, method_metrics, metrics, preview=preview)

    @staticmethod
    def _chosen_frame(
        ctx: JobContext[PrtConfig],
        model: PrtNetwork,
        box: np.ndarray,
        objects: np.ndarray,
        report: ReportView,
        method_metrics: dict[str, float],
    ) -> tuple[Frame, float, PrtConfig]:
        """The frame `frame_spp` chooses among the config's counts (one when the config fixes it) by their
        counted cost, its median time (the report's), and the config with its spp (the artifact's)."""
        config = ctx.config
        candidates = frame_candidates(model, box, objects, report, config, ctx.seed)
        for c in candidates:
            ctx.log(str(c))
            method_metrics[f"frame_spp.{c.spp}.cost_rays"] = c.point.seconds_per_frame
            method_metrics[f"frame_spp.{c.spp}.cost_ratio_flip"] = c.ratio_flip
            method_metrics[f"frame_spp.{c.spp}.cost_ratio_psnr"] = c.ratio_psnr
        chosen = best(candidates)
        how = "the config's" if config.evaluation_spp is not None else "counted, `frame_spp`"
        ctx.log(f"the artifact's frame: direct light at {chosen.spp} spp ({how})")
        seconds = timed(chosen, model, box, objects, report, config, ctx.seed)
        config = config.model_copy(update={"evaluation_spp": chosen.spp})
        return chosen.frame, seconds, config
