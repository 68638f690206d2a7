"""Equal-time comparison with path tracing: how long a path tracer's (seconds, error) curve takes to reach
an error, and a frame's time over that (below 1, the frame beats path tracing at its own error)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the report imports this module to fill in its ratios
    from workers.runtime.report import SpeedErrorPoint

METRICS = ("flip", "psnr")


def seconds_at_error(
    seconds: Sequence[float], errors: Sequence[float], target: float, log_error: bool = True
) -> float:
    """The time a peer's curve of (seconds, error) points needs to reach error `target`: log seconds
    interpolated against log error (against the error itself with `log_error` False, for a log already,
    such as negated dB). The peer's cheapest time where `target` is above all its errors; inf where it is
    below all of them (the peer never gets there)."""
    log_seconds = np.log(np.asarray(seconds, np.float64))
    e = np.log(np.asarray(errors, np.float64)) if log_error else np.asarray(errors, np.float64)
    with np.errstate(divide="ignore"):  # an error of 0 is below every curve: -inf
        t = float(np.log(target)) if log_error else float(target)
    if t < e.min():
        return math.inf
    if t >= e.max():
        return float(min(seconds))
    order = np.argsort(e)
    return float(np.exp(np.interp(t, e[order], log_seconds[order])))


def equal_time_ratio(frame: SpeedErrorPoint, curve: Sequence[SpeedErrorPoint], metric: str) -> float:
    """`frame`'s seconds over the path tracer's at the frame's error by `metric`, "flip" (interpolated
    log-log) or "psnr" (log seconds against dB). Where the curve never reaches the frame's error, the ratio
    to its longest render: an upper bound, since path tracing would need longer still. A frame whose error
    is NaN (a broken model) is infinitely slow."""
    if metric not in METRICS:
        raise ValueError(f"metric: 'flip' or 'psnr', got {metric!r}")

    def error(point: SpeedErrorPoint) -> float:  # FLIP, or negated dB (a log already)
        return point.error.flip if metric == "flip" else -point.error.psnr

    if math.isnan(error(frame)):
        return math.inf
    seconds = [p.seconds_per_frame for p in curve]
    traced = seconds_at_error(seconds, [error(p) for p in curve], error(frame), log_error=metric == "flip")
    return frame.seconds_per_frame / (traced if math.isfinite(traced) else max(seconds))
