"""The artifact's frame, chosen by the job: of the counts in `PrtConfig.frame_spp_choices` (4 to 64 when
`evaluation_spp` is None, else that one, only timed), the direct light's spp whose frame of the report's
view beats path tracing by the widest margin at equal time by both of the report's measures (the smallest
of the larger of its two equal-time ratios, by FLIP and by PSNR, `workers.runtime.equal_time`).

Why a job chooses: the network's indirect light costs the same at every count, while the direct light's
noise falls with it, so the best count is where that noise meets the network's own error at the price of a
sample. Both differ by scene: where the network's error is high (glossy_row) the frame reaches it with few
samples and more only cost time; where it is low (env_lit_objects) the direct light's noise is most of the
frame's error and more samples pay (bench_prt's frame curve: best by FLIP at 8 spp on one, 32 on the other).
The price of a sample against the network's differs by machine as well (bfloat16 products, Embree), so the
choice is timed on the machine that trains; the job logs every count's figures and reports them."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np

from workers.models.prt.config import PrtConfig
from workers.models.prt.evaluate import ReportView
from workers.models.prt.frame import Frame, render_frame
from workers.models.prt.network import PrtNetwork
from workers.runtime.equal_time import METRICS, equal_time_ratio
from workers.runtime.report import SpeedErrorPoint, TimedImage

TIMED_RENDERS = 3  # per count, and per point of path tracing's curve: their median time


@dataclass(frozen=True)
class FrameCandidate:
    spp: int
    frame: Frame  # as first rendered
    point: SpeedErrorPoint  # its median time and its error against the report's reference
    ratio_flip: float
    ratio_psnr: float

    @property
    def ratio(self) -> float:
        """The larger of its equal-time ratios: below 1, it beats path tracing by FLIP and by PSNR."""
        return max(self.ratio_flip, self.ratio_psnr)

    def __str__(self) -> str:
        error = self.point.error
        return (
            f"frame at {self.spp} spp: {self.point.seconds_per_frame * 1e3:.0f} ms, FLIP {error.flip:.4f}, "
            f"{error.psnr:.2f} dB; equal-time ratio by FLIP {self.ratio_flip:.2f}, "
            f"by PSNR {self.ratio_psnr:.2f}"
        )


def frame_candidates(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    report: ReportView,
    config: PrtConfig,
    seed: int,
) -> list[FrameCandidate]:
    """The report view's frame at each of `frame_spp_choices` (the config's denoising and checkerboard)
    against the report's path-tracing curve of the same view (`report.view`). Both are timed as the median
    of `TIMED_RENDERS` renders, and the curve keeps its medians, so that the report gives the chosen frame
    the ratio it was chosen by."""
    reference = report.view.reference()
    traced = [report.view.frame(spp, TIMED_RENDERS) for spp in report.view.curve_spp()]
    curve = [SpeedErrorPoint.measure(frame, reference) for frame in traced]

    def rendered(spp: int) -> Frame:
        return render_frame(
            model, box, objects, report.tracer, report.cube, report.camera, k=config.wavelets,
            weighting=config.selection, spp=spp, seed=seed, denoise=config.denoise_direct,
            checkerboard=config.checkerboard,
        )  # fmt: skip

    candidates = []
    for spp in config.frame_spp_choices:
        frames = [rendered(spp) for _ in range(TIMED_RENDERS)]
        timed = TimedImage(f"{spp} spp", frames[0].image, statistics.median(f.seconds for f in frames))
        point = SpeedErrorPoint.measure(timed, reference)
        ratios = (equal_time_ratio(point, curve, metric) for metric in METRICS)
        candidates.append(FrameCandidate(spp, frames[0], point, *ratios))
    return candidates


def best(candidates: list[FrameCandidate]) -> FrameCandidate:
    """The candidate with the smallest `ratio` (the fewer samples on a tie)."""
    return min(candidates, key=lambda c: (c.ratio, c.spp))
