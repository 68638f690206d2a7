"""The artifact's frame, chosen by the job: of the counts in `PrtConfig.frame_spp_choices` (4 to 64 when
`evaluation_spp` is None, else that one), the direct light's spp whose frame of the report's view beats
path tracing by the widest margin at equal cost by both of the report's measures (the smallest of the
larger of its two equal-cost ratios, by FLIP and by PSNR, `workers.runtime.equal_time`).

Why a job chooses: the network's indirect light costs the same at every count, while the direct light's
noise falls with it, so the best count is where that noise meets the network's own error at the price of a
sample. Both differ by scene: where the network's error is high (glossy_row) the frame reaches it with few
samples and more only cost time; where it is low (env_lit_objects) the direct light's noise is most of the
frame's error and more samples pay (bench_prt's frame curve: best by FLIP at 8 spp on one, 32 on the other).

Why cost is counted, not timed: the count shapes what is served, so the same job must choose the same one on
any machine under any load (timed, one job chose 4 spp on a quiet machine and 8 beside a busy one). A
frame's cost is the rays it traces plus its network's FLOPs at `PrtConfig.flops_per_ray`, path tracing's
the rays it traces. The report still times the chosen frame against path tracing (`TIMED_RENDERS`)."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np

from workers.models.prt.config import PrtConfig
from workers.models.prt.evaluate import ReportView
from workers.models.prt.frame import Frame, render_frame
from workers.models.prt.network import PrtNetwork
from workers.runtime.equal_time import METRICS, equal_time_ratio
from workers.runtime.report import ImageError, SpeedErrorPoint

TIMED_RENDERS = 3  # of the chosen frame, and per point of path tracing's curve: the report's median times


@dataclass(frozen=True)
class FrameCandidate:
    spp: int
    frame: Frame
    point: SpeedErrorPoint  # `seconds_per_frame` holds its counted cost (`cost`), in rays
    ratio_flip: float
    ratio_psnr: float

    @property
    def ratio(self) -> float:
        """The larger of its equal-cost ratios: below 1, it beats path tracing by FLIP and by PSNR."""
        return max(self.ratio_flip, self.ratio_psnr)

    def __str__(self) -> str:
        error = self.point.error
        return (
            f"frame at {self.spp} spp: costs {self.point.seconds_per_frame:.3g} rays, FLIP {error.flip:.4f}, "
            f"{error.psnr:.2f} dB; equal-cost ratio by FLIP {self.ratio_flip:.2f}, "
            f"by PSNR {self.ratio_psnr:.2f}"
        )


def cost(frame: Frame, config: PrtConfig) -> float:
    """The frame's counted cost in traced rays: its own and its network's FLOPs at `flops_per_ray`."""
    return frame.rays + frame.network_flops / config.flops_per_ray


def report_frame(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    report: ReportView,
    config: PrtConfig,
    seed: int,
    spp: int,
) -> Frame:
    """The report view's frame with the direct light at `spp` (the config's denoising and checkerboard)."""
    return render_frame(
        model, box, objects, report.tracer, report.cube, report.camera, k=config.wavelets,
        weighting=config.selection, spp=spp, seed=seed, denoise=config.denoise_direct,
        checkerboard=config.checkerboard,
    )  # fmt: skip


def frame_candidates(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    report: ReportView,
    config: PrtConfig,
    seed: int,
) -> list[FrameCandidate]:
    """The report view's frame at each of `frame_spp_choices` against the report's path-tracing curve of
    the same view (`report.view`), each at its counted cost."""
    reference = report.view.reference()
    curve = [
        SpeedErrorPoint(
            label=f"{spp} spp",
            seconds_per_frame=report.view.rays(spp),
            error=ImageError.measure(report.view.frame(spp).image, reference),
        )
        for spp in report.view.curve_spp()
    ]
    candidates = []
    for spp in config.frame_spp_choices:
        frame = report_frame(model, box, objects, report, config, seed, spp)
        error = ImageError.measure(frame.image, reference)
        point = SpeedErrorPoint(label=f"{spp} spp", seconds_per_frame=cost(frame, config), error=error)
        ratios = (equal_time_ratio(point, curve, metric) for metric in METRICS)
        candidates.append(FrameCandidate(spp, frame, point, *ratios))
    return candidates


def best(candidates: list[FrameCandidate]) -> FrameCandidate:
    """The candidate with the smallest `ratio` (the fewer samples on a tie)."""
    return min(candidates, key=lambda c: (c.ratio, c.spp))


def timed(
    chosen: FrameCandidate,
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    report: ReportView,
    config: PrtConfig,
    seed: int,
) -> float:
    """The chosen frame's median seconds over `TIMED_RENDERS` renders, after timing the report's path
    tracing as many times: the report's honest speed figures, which choose nothing."""
    for spp in report.view.curve_spp():
        report.view.frame(spp, TIMED_RENDERS)
    seconds = [chosen.frame.seconds]
    for _ in range(TIMED_RENDERS - 1):
        seconds.append(report_frame(model, box, objects, report, config, seed, chosen.spp).seconds)
    return statistics.median(seconds)
