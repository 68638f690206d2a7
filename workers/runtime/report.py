"""The report every trained model ships with: its cost, and its error next to plain path tracing's.

A neural representation is only worth having if it beats the path tracer it replaces at equal time, so the
report puts the model's (time per frame, error) point on the same axes as path tracing at several sample
counts, and records the path-traced image that took as long as the model's frame.
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
from pydantic import BaseModel

from workers.nn.metrics import flip, psnr, relative_mse
from workers.runtime.training import TrainResult

REPORT_FILE = "report.json"
PLOT_FILE = "speed_error.png"
MEDIA_TYPES = {REPORT_FILE: "application/json", PLOT_FILE: "image/png"}


class ImageError(BaseModel):
    """Error of one image against the reference path tracer's converged image."""

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

    kind: str
    training_seconds: float
    training_samples: int
    training_samples_per_s: float
    seconds_per_query: float | None = None
    parameter_bytes: int
    peak_rss_bytes: int
    peak_gpu_bytes: int | None = None
    model: SpeedErrorPoint
    path_tracing_equal_time: SpeedErrorPoint
    path_tracing: list[SpeedErrorPoint]
    method_metrics: dict[str, float] = {}

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


def parameter_bytes(model: torch.nn.Module) -> int:
    """Bytes of parameters and buffers: what the exported weights weigh."""
    tensors = [*model.parameters(), *model.buffers()]
    return sum(t.numel() * t.element_size() for t in tensors)


def peak_rss_bytes() -> int:
    """Peak resident memory of this process so far (Linux reports kilobytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def nearest_in_time(frames: Sequence[TimedImage], seconds: float) -> TimedImage:
    """The frame whose time is nearest `seconds` in ratio: path tracing "at equal time" to a model."""
    return min(frames, key=lambda f: abs(np.log(max(f.seconds, 1e-9) / max(seconds, 1e-9))))


def build_report(
    kind: str,
    training: TrainResult,
    model: torch.nn.Module,
    model_frame: TimedImage,
    path_tracing_equal_time: TimedImage,
    path_tracing: Sequence[TimedImage],
    reference: np.ndarray,
    seconds_per_query: float | None = None,
    method_metrics: dict[str, float] | None = None,
) -> Report:
    """Measure every frame against `reference` and gather the model's cost into a Report."""
    if not path_tracing:
        raise ValueError(
            "the speed-against-error curve needs path-traced frames at one sample count at least"
        )
    return Report(
        kind=kind,
        training_seconds=training.seconds,
        training_samples=training.samples,
        training_samples_per_s=training.samples_per_s,
        seconds_per_query=seconds_per_query,
        parameter_bytes=parameter_bytes(model),
        peak_rss_bytes=peak_rss_bytes(),
        peak_gpu_bytes=torch.cuda.max_memory_allocated() if torch.cuda.is_available() else None,
        model=SpeedErrorPoint.measure(model_frame, reference),
        path_tracing_equal_time=SpeedErrorPoint.measure(path_tracing_equal_time, reference),
        path_tracing=[SpeedErrorPoint.measure(frame, reference) for frame in path_tracing],
        method_metrics=method_metrics or {},
    )
