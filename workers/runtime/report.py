"""The report every trained model ships with: its cost, and its error next to plain path tracing's.

A neural representation is only worth having if it beats the path tracer it replaces at equal time, so the
report puts the model's (time per frame, error) point on the same axes as path tracing at the spp of
`PATH_TRACING_SPP`, records the path-traced image that took as long as the model's frame and gives the
equal-time ratio, the frame's time over path tracing's at the frame's own error by FLIP and by PSNR
(`equal_time`: below 1, the model is faster than the path tracer it replaces). Every kind
fills the same fields, so reports of different kinds can be compared and plotted together. A model whose
frame is worse than one sample per pixel of path tracing is flagged (`worse_than_one_spp`): training ran
but produced nothing worth shipping, and the job's log and the CLI say so.
"""

from __future__ import annotations

import io
import resource
from collections.abc import Sequence
from dataclasses import dataclass

import fsspec
import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
from pydantic import BaseModel, ConfigDict

from workers.nn.metrics import flip, psnr, relative_mse
from workers.runtime.equal_time import METRICS, equal_time_ratio
from workers.runtime.training import TrainResult

PATH_TRACING_SPP = (1, 4, 16, 64, 256)  # the curve's sample counts (those below the reference's spp)
REPORT_FILE = "report.json"
PLOT_FILE = "speed_error.png"
MEDIA_TYPES = {REPORT_FILE: "application/json", PLOT_FILE: "image/png"}


# JSON has no NaN: figures that are NaN (the FLIP of a NaN frame, a mean over nothing) are written as the
# string "NaN", which reads back as NaN, rather than as null, which does not read back as a float.
NAN_AS_STRING = ConfigDict(ser_json_inf_nan="strings")


class ImageError(BaseModel):
    """Error of one image against the reference path tracer's converged image."""

    model_config = NAN_AS_STRING

    flip: float
    psnr: float
    relative_mse: float

    @classmethod
    def measure(cls, image: np.ndarray, reference: np.ndarray) -> ImageError:
        return cls(
            flip=flip(reference, image),
            psnr=psnr(reference, image),
            relative_mse=relative_mse(reference, image),
        )


@dataclass(frozen=True)
class TimedImage:
    """A rendered frame (float32 linear RGB) and the wall time it took, as the caller measured it."""

    label: str
    image: np.ndarray
    seconds: float


class SpeedErrorPoint(BaseModel):
    model_config = NAN_AS_STRING

    label: str
    seconds_per_frame: float
    error: ImageError

    @classmethod
    def measure(cls, frame: TimedImage, reference: np.ndarray) -> SpeedErrorPoint:
        return cls(
            label=frame.label,
            seconds_per_frame=frame.seconds,
            error=ImageError.measure(frame.image, reference),
        )


class Report(BaseModel):
    """Speed, memory and error of one trained model, stored as JSON next to its weights."""

    model_config = NAN_AS_STRING

    kind: str
    training_seconds: float
    training_samples: int
    training_samples_per_s: float
    seconds_per_query: float | None = None
    parameter_bytes: int  # as the artifact stores them (e.g. float16 weights)
    peak_rss_bytes: int
    peak_gpu_bytes: int | None = None
    model: SpeedErrorPoint
    path_tracing_equal_time: SpeedErrorPoint
    path_tracing: list[SpeedErrorPoint]
    worse_than_one_spp: bool = False  # the model's FLIP exceeds 1-spp path tracing's
    # "flip", "psnr": the frame's time over path tracing's at its error (`equal_time.equal_time_ratio`)
    equal_time_ratio: dict[str, float] = {}
    method_metrics: dict[str, float] = {}

    def warnings(self) -> list[str]:
        """What a person must read before using the model."""
        if not self.worse_than_one_spp:
            return []
        one = self.path_tracing[0]
        return [
            f"the {self.kind} model's frame is worse than {one.label} path tracing of the same view "
            f"(FLIP {self.model.error.flip:.3f} against {one.error.flip:.3f}): the model is not usable; "
            "train longer or check the scene"
        ]

    def plot_png(self) -> bytes:
        """Time per frame against FLIP and relative MSE, model against path tracing, as PNG bytes."""
        figure = Figure(figsize=(9, 4), layout="constrained")
        FigureCanvasAgg(figure)
        traced = sorted(self.path_tracing, key=lambda p: p.seconds_per_frame)
        for axes, metric, title in zip(
            figure.subplots(1, 2), ("flip", "relative_mse"), ("FLIP", "relative MSE"), strict=True
        ):
            axes.plot(
                [p.seconds_per_frame for p in traced],
                [getattr(p.error, metric) for p in traced],
                "o-",
                color="tab:gray",
                label="path tracing",
            )
            for point in traced:
                axes.annotate(
                    point.label,
                    (point.seconds_per_frame, getattr(point.error, metric)),
                    fontsize=7,
                    textcoords="offset points",
                    xytext=(3, 3),
                )
            equal_time = self.path_tracing_equal_time
            axes.plot(
                equal_time.seconds_per_frame,
                getattr(equal_time.error, metric),
                "s",
                color="tab:blue",
                label=f"path tracing at equal time ({equal_time.label})",
            )
            axes.plot(
                self.model.seconds_per_frame,
                getattr(self.model.error, metric),
                "*",
                markersize=14,
                color="tab:red",
                label=f"{self.kind} ({self.model.label})",
            )
            axes.set(xscale="log", yscale="log", xlabel="seconds per frame", ylabel=title, title=title)
            for axis in (axes.xaxis, axes.yaxis):  # 1-2-5 labels: a decade alone may hold every point
                axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                axis.set_major_formatter(FormatStrFormatter("%g"))
                axis.set_minor_formatter(NullFormatter())
            axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=7)
        buffer = io.BytesIO()
        figure.savefig(buffer, format="png", dpi=110)
        return buffer.getvalue()

    def files(self) -> dict[str, bytes]:
        """The report as artifact files: JSON and the speed-against-error plot."""
        return {REPORT_FILE: self.model_dump_json(indent=2).encode(), PLOT_FILE: self.plot_png()}

    def write(self, folder: str) -> dict[str, tuple[str, str]]:
        """Write the report files into `folder` (a local path or an fsspec URL); returns them as a kind's
        `RunOutput.files` entries: name -> (path, media type)."""
        fs, root = fsspec.core.url_to_fs(str(folder))
        fs.makedirs(root, exist_ok=True)
        written = {}
        for name, content in self.files().items():
            fs.pipe_file(f"{root}/{name}", content)
            written[name] = (f"{str(folder).rstrip('/')}/{name}", MEDIA_TYPES[name])
        return written

    @classmethod
    def read(cls, folder: str) -> Report:
        fs, root = fsspec.core.url_to_fs(str(folder))
        return cls.model_validate_json(fs.cat_file(f"{root}/{REPORT_FILE}"))


def parameter_bytes(model: torch.nn.Module, stored_dtype: torch.dtype | None = None) -> int:
    """Bytes of the model's trained parameters as exported: at `stored_dtype` (the artifact's precision)
    where given, else at their own. Buffers are not counted: kinds rebuild theirs (row maps, keys) on
    load and list what else they store in their own figures."""
    itemsize = (lambda p: stored_dtype.itemsize) if stored_dtype is not None else (lambda p: p.element_size())
    return sum(p.numel() * itemsize(p) for p in model.parameters())


def peak_rss_bytes() -> int:
    """Peak resident memory of this process so far (Linux reports kilobytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def nearest_in_time(frames: Sequence[TimedImage], seconds: float) -> TimedImage:
    """The frame whose time is nearest `seconds` in ratio: path tracing "at equal time" to a model."""
    return frames[_nearest_index(frames, seconds)]


def _nearest_index(frames: Sequence[TimedImage], seconds: float) -> int:
    ratio = [abs(np.log(max(f.seconds, 1e-9) / max(seconds, 1e-9))) for f in frames]
    return int(np.argmin(ratio))


def build_report(
    kind: str,
    training: TrainResult,
    stored_bytes: int,
    model_frame: TimedImage,
    path_tracing: Sequence[TimedImage],
    reference: np.ndarray,
    seconds_per_query: float | None = None,
    method_metrics: dict[str, float] | None = None,
) -> Report:
    """Measure every frame against `reference` and gather the model's cost into a Report.

    `path_tracing` is the curve in increasing spp; the equal-time frame is the one nearest the model's
    frame time, and the first frame (1 spp) is the floor below which a model is flagged."""
    if not path_tracing:
        raise ValueError(
            "the speed-against-error curve needs path-traced frames at one sample count at least"
        )
    model = SpeedErrorPoint.measure(model_frame, reference)
    curve = [SpeedErrorPoint.measure(frame, reference) for frame in path_tracing]
    return Report(
        kind=kind,
        training_seconds=training.seconds,
        training_samples=training.samples,
        training_samples_per_s=training.samples_per_s,
        seconds_per_query=seconds_per_query,
        parameter_bytes=stored_bytes,
        peak_rss_bytes=peak_rss_bytes(),
        peak_gpu_bytes=torch.cuda.max_memory_allocated() if torch.cuda.is_available() else None,
        model=model,
        path_tracing_equal_time=curve[_nearest_index(path_tracing, model_frame.seconds)],
        path_tracing=curve,
        worse_than_one_spp=not model.error.flip <= curve[0].error.flip,  # NaN counts as worse
        equal_time_ratio={metric: equal_time_ratio(model, curve, metric) for metric in METRICS},
        method_metrics=method_metrics or {},
    )
