import numpy as np
import pytest
import torch

from workers.runtime.equal_time import equal_time_ratio
from workers.runtime.report import (
    PLOT_FILE,
    REPORT_FILE,
    Report,
    TimedImage,
    build_report,
    nearest_in_time,
    parameter_bytes,
)
from workers.runtime.training import TrainResult

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def noisy(reference: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (reference + rng.normal(0.0, sigma, reference.shape)).clip(0).astype(np.float32)


@pytest.fixture(scope="module")
def report() -> Report:
    rng = np.random.default_rng(0)
    reference = rng.uniform(0.0, 2.0, (32, 32, 3)).astype(np.float32)
    path_tracing = [
        TimedImage(f"{spp} spp", noisy(reference, 1.0 / np.sqrt(spp), spp), seconds=0.01 * spp)
        for spp in (1, 4, 16)
    ]
    return build_report(
        kind="lod",
        training=TrainResult(steps=100, final_loss=0.1, best_loss=0.09, seconds=4.0, samples=8000),
        stored_bytes=parameter_bytes(torch.nn.Linear(8, 4)),
        model_frame=TimedImage("256x256 frame", noisy(reference, 0.05, 99), seconds=0.02),
        path_tracing=path_tracing,
        reference=reference,
        seconds_per_query=1e-6,
        method_metrics={"visibility_accuracy": 0.97},
    )


def test_report_measures_error_against_the_reference(report):
    assert report.training_samples_per_s == 2000.0
    assert report.parameter_bytes == (8 * 4 + 4) * 4
    assert report.peak_rss_bytes > 10 * 2**20
    errors = [point.error for point in report.path_tracing]
    assert [e.relative_mse for e in errors] == sorted((e.relative_mse for e in errors), reverse=True)
    assert [e.psnr for e in errors] == sorted(e.psnr for e in errors)
    assert report.model.error.flip < report.path_tracing_equal_time.error.flip
    assert report.path_tracing_equal_time == report.path_tracing[0]  # 0.01 s is nearest 0.02 s
    assert not report.worse_than_one_spp and report.warnings() == []


def test_the_report_gives_the_equal_time_ratio_on_its_own_curve(report):
    """The model's frame (0.02 s, noise 0.05) is cleaner than the whole curve (16 spp: noise 0.25, 0.16 s),
    so its ratio is the bound against the longest render."""
    for metric in ("flip", "psnr"):
        assert report.equal_time_ratio[metric] == equal_time_ratio(report.model, report.path_tracing, metric)
        assert report.equal_time_ratio[metric] == pytest.approx(0.02 / 0.16)


def test_json_round_trip_and_plot(report, tmp_path):
    written = report.write(str(tmp_path / "report"))
    assert written == {
        REPORT_FILE: (str(tmp_path / "report" / REPORT_FILE), "application/json"),
        PLOT_FILE: (str(tmp_path / "report" / PLOT_FILE), "image/png"),
    }
    assert Report.read(str(tmp_path / "report")) == report
    png = (tmp_path / "report" / PLOT_FILE).read_bytes()
    assert png.startswith(PNG_SIGNATURE)
    assert (tmp_path / "report" / REPORT_FILE).read_text().startswith("{")


def test_equal_time_is_the_nearest_frame_in_ratio():
    frames = [TimedImage(f"{s} s", np.zeros((1, 1, 3)), s) for s in (0.1, 1.0, 8.0)]
    assert nearest_in_time(frames, 0.25).seconds == 0.1  # 2.5x from 0.1, 4x from 1.0
    assert nearest_in_time(frames, 2.0).seconds == 1.0  # 2x from 1.0, 4x from 8.0
    assert nearest_in_time(frames, 3.0).seconds == 8.0  # 3x from 1.0, 2.7x from 8.0
    assert nearest_in_time(frames, 0.0).seconds == 0.1


def test_parameter_bytes_count_parameters_at_their_stored_precision():
    model = torch.nn.BatchNorm1d(10).to(torch.float64)  # running statistics are buffers: not counted
    assert parameter_bytes(model) == 2 * 10 * 8
    assert parameter_bytes(model, torch.float16) == 2 * 10 * 2


@pytest.mark.parametrize(
    "broken",
    [np.zeros((32, 32, 3), np.float32), np.full((32, 32, 3), np.nan, np.float32)],
    ids=["black", "nan"],
)
def test_a_model_worse_than_one_spp_path_tracing_is_flagged(broken):
    """A black (or NaN) frame where the scene is lit: the report says the model is not usable."""
    rng = np.random.default_rng(1)
    reference = rng.uniform(0.5, 2.0, (32, 32, 3)).astype(np.float32)
    curve = [
        TimedImage(f"{spp} spp", noisy(reference, 1.0 / np.sqrt(spp), spp), 0.01 * spp) for spp in (1, 4)
    ]
    training = TrainResult(steps=1, final_loss=0.0, best_loss=0.0, seconds=1.0, samples=1)
    report = build_report("lod", training, 4, TimedImage("model", broken, 0.01), curve, reference)
    assert report.worse_than_one_spp
    assert "worse than 1 spp path tracing" in report.warnings()[0]


def test_a_report_needs_a_path_tracing_curve(report):
    with pytest.raises(ValueError, match="path-traced frames"):
        build_report(
            kind="lod",
            training=TrainResult(steps=1, final_loss=0.0, best_loss=0.0, seconds=1.0, samples=1),
            stored_bytes=4,
            model_frame=TimedImage("frame", np.zeros((4, 4, 3), np.float32), 0.1),
            path_tracing=[],
            reference=np.zeros((4, 4, 3), np.float32),
        )
