"""The report's quality gate (`tests.support.quality.report_failures`, which every kind's integration test
runs) on frames with injected faults: a NaN frame and a black one fail it, a good one passes; a NaN
figure survives the report's JSON, and a mean over no pixel is NaN."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.support.quality import REPORT_CHECKS, report_failures
from workers.models.lod.evaluate import masked_mean
from workers.runtime.report import Report, TimedImage, build_report
from workers.runtime.training import TrainResult

REFERENCE = np.random.default_rng(0).uniform(0.05, 1.0, (24, 24, 3)).astype(np.float32)


def report_of(frame: np.ndarray) -> Report:
    """A report of `frame` against path tracing at 1 and 4 spp (noise of a one-sample estimate)."""
    rng = np.random.default_rng(1)
    traced = [
        TimedImage(f"{spp} spp", (REFERENCE * rng.exponential(1.0, REFERENCE.shape) ** (1 / spp)), 0.01 * spp)
        for spp in (1, 4)
    ]
    training = TrainResult(steps=1, final_loss=0.0, best_loss=0.0, seconds=1.0, samples=1)
    return build_report(
        "test", training, 8, TimedImage("frame", frame.astype(np.float32), 0.01), traced, REFERENCE
    )


def nan_frame() -> np.ndarray:
    frame = REFERENCE.copy()
    frame[5:9, 5:9] = np.nan  # a few broken pixels, the rest exact
    return frame


def test_a_good_frame_passes():
    assert report_failures(report_of(REFERENCE * 1.01)) == {}


@pytest.mark.parametrize(
    "frame, failing",
    [(nan_frame(), set(REPORT_CHECKS)), (np.zeros_like(REFERENCE), {"beats_one_spp"})],
    ids=["nan", "black"],
)
def test_a_broken_frame_fails(frame, failing):
    report = report_of(frame)
    assert set(report_failures(report)) == failing
    assert report.worse_than_one_spp and report.warnings()


def test_a_nan_figure_reads_back_as_nan(tmp_path):
    """JSON has no NaN: the report writes it as "NaN", which reads back (null would not read as a float)."""
    report = report_of(nan_frame()).model_copy(update={"method_metrics": {"normal_error_deg": math.nan}})
    report.write(str(tmp_path))
    read = Report.read(str(tmp_path))
    assert math.isnan(read.model.error.flip) and math.isnan(read.method_metrics["normal_error_deg"])
    assert read.worse_than_one_spp


def test_a_mean_over_no_pixel_is_nan_not_a_perfect_score():
    values = np.ones((4, 4))
    assert masked_mean(values, values > 0) == 1.0
    assert math.isnan(masked_mean(values, values < 0))
