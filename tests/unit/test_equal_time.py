"""The equal-time ratio against a path tracer's curve: exact on the power laws it interpolates, bounded
where the curve does not reach the frame's error."""

from __future__ import annotations

import math

import pytest

from workers.runtime.equal_time import equal_time_ratio, seconds_at_error
from workers.runtime.report import ImageError, SpeedErrorPoint

SECONDS = (0.01, 0.04, 0.16, 0.64)


def point(seconds: float, flip: float, psnr: float) -> SpeedErrorPoint:
    error = ImageError(flip=flip, psnr=psnr, relative_mse=0)
    return SpeedErrorPoint(label="", seconds_per_frame=seconds, error=error)


def monte_carlo(seconds: float) -> SpeedErrorPoint:
    """A path tracer whose error falls as 1 / sqrt(time): FLIP-like, and 10 dB per 10x time."""
    return point(seconds, 0.1 * math.sqrt(0.01 / seconds), 20 + 10 * math.log10(seconds / 0.01))


CURVE = [monte_carlo(s) for s in SECONDS]


def test_a_frame_at_path_tracings_error_in_half_its_time_has_ratio_one_half_by_either_metric():
    reached = monte_carlo(0.08)  # between the curve's points
    frame = point(0.04, reached.error.flip, reached.error.psnr)
    assert equal_time_ratio(frame, CURVE, "flip") == pytest.approx(0.5)
    assert equal_time_ratio(frame, CURVE, "psnr") == pytest.approx(0.5)


def test_beyond_the_curve_the_ratio_is_against_its_longest_render_an_upper_bound():
    frame = point(0.32, 0.001, 60.0)  # cleaner than the curve's cleanest
    assert seconds_at_error(SECONDS, [p.error.flip for p in CURVE], 0.001) == math.inf
    assert equal_time_ratio(frame, CURVE, "flip") == pytest.approx(0.5)
    assert equal_time_ratio(frame, CURVE, "psnr") == pytest.approx(0.5)


def test_worse_than_the_curve_the_ratio_is_against_its_cheapest_render():
    frame = point(0.05, 0.5, 5.0)
    assert equal_time_ratio(frame, CURVE, "flip") == pytest.approx(5.0)
    assert equal_time_ratio(frame, CURVE, "psnr") == pytest.approx(5.0)


def test_an_unknown_metric_is_refused_by_name():
    with pytest.raises(ValueError, match="metric: 'flip' or 'psnr', got 'ssim'"):
        equal_time_ratio(CURVE[0], CURVE, "ssim")


def test_a_perfect_frame_is_bounded_and_a_broken_one_never_beats_path_tracing():
    perfect = point(0.32, 0.0, math.inf)
    assert equal_time_ratio(perfect, CURVE, "flip") == equal_time_ratio(perfect, CURVE, "psnr") == 0.5
    broken = point(0.01, math.nan, math.nan)
    assert equal_time_ratio(broken, CURVE, "flip") == equal_time_ratio(broken, CURVE, "psnr") == math.inf
