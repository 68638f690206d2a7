"""The `explore` kind end to end through the job driver's `run_job` (no Ray actor): plan, train by active
exploration, export, report. A short job's artifact serves `:render` at named variable values through the
inference service's loader, and bad values are errors naming the field; a job stopped mid-training resumes
(chains, store and all) to the uninterrupted job's weights bit for bit; the example job's network (slow)
beats a black renderer at every fixed configuration and 1-spp path tracing of the report's view."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from tests.support.jobs import assert_resumes_to_the_uninterrupted_weights, progress_steps, run_kind_job
from tests.support.quality import report_failures
from workers.models.explore import artifact, evaluate
from workers.models.explore.evaluate import configurations, reference_images
from workers.models.explore.source import PatchSource, PatchSourceConfig
from workers.models.registry import QUERY, RENDER, get_inference, get_kind
from workers.nn.metrics import dssim, mape
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.runtime.report import Report
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

SEED = 5
KIND = get_kind("explore")
SCENE = KIND.example.scene
CONFIG = KIND.resolve_config("quick", KIND.example.overrides)


# a checkpoint at step 15, after the bootstrap: the chains sit somewhere and steps reuse stored patches
SHORT = {
    "bootstrap": 4,
    "train": {"steps": 30, "checkpoint_every": 15, "progress_every": 5},
    "evaluation_configurations": 1,
}
SHORT_TRAIN = KIND.resolve_config("quick", SHORT).train


def run(folder: Path, overrides: dict) -> Path:
    _, outcome = run_kind_job("explore", get_builtin(SCENE), folder, overrides, seed=SEED)
    assert outcome.state == "succeeded", outcome.error
    return folder / "out"


@dataclass
class ShortRun:
    outcome: object
    events: list


def run_short(folder: Path, cancel_after_step: int | None = None) -> ShortRun:
    events: list = []
    _, outcome = run_kind_job(
        "explore", get_builtin(SCENE), folder, SHORT, seed=SEED, events=events,
        cancel_after_step=cancel_after_step,
    )  # fmt: skip
    return ShortRun(outcome, events)


@pytest.fixture(scope="module")
def short_job(tmp_path_factory) -> Path:
    return run(tmp_path_factory.mktemp("explore-short"), SHORT)


def test_a_job_stopped_mid_training_resumes_to_the_uninterrupted_weights(short_job, tmp_path):
    assert_resumes_to_the_uninterrupted_weights(
        run_short, short_job.parent, tmp_path, SHORT_TRAIN, ["checkpoints/{final}", f"out/{artifact.WEIGHTS}"]
    )


def test_the_uniform_baseline_trains_at_equal_time_is_compared_in_the_report_and_resumes(short_job, tmp_path):
    steps, every = SHORT_TRAIN.steps, SHORT_TRAIN.checkpoint_every
    options = SHORT | {"uniform_baseline": True}
    stopped_events, resumed_events = [], []
    _, stopped = run_kind_job(
        "explore", get_builtin(SCENE), tmp_path, options, seed=SEED, events=stopped_events,
        cancel_after_step=steps + every + 1,
    )  # fmt: skip
    assert stopped.state == "cancelled"
    assert progress_steps(stopped_events)[-1] > steps + every  # stopped inside the baseline
    _, outcome = run_kind_job(
        "explore", get_builtin(SCENE), tmp_path, options, seed=SEED, events=resumed_events
    )
    assert outcome.state == "succeeded", outcome.error
    assert progress_steps(resumed_events)[0] > steps + every  # resumed there, not at step 0
    figures = Report.read(str(tmp_path / "out")).method_metrics
    baseline_steps = figures["uniform.steps"]
    assert figures["active.steps"] == steps <= baseline_steps
    # the resumed job gave its baseline the steps the first decided (the progress's total once decided)
    totals = {e.total for e in stopped_events + resumed_events if e.type == "progress" and e.step > steps}
    assert totals == {steps + baseline_steps}
    assert (tmp_path / "checkpoints" / "uniform" / f"step-{int(baseline_steps):09d}").is_dir()
    assert figures["uniform.seconds"] > 0 and figures["active.seconds"] > 0
    ratio = figures["configurations.dssim"] / figures["uniform.dssim"]
    assert figures["active_over_uniform.dssim"] == pytest.approx(ratio)
    assert outcome.metrics["dssim_over_uniform"] == pytest.approx(ratio)
    # the baseline is a measurement, not part of the artifact
    assert Report.read(str(tmp_path / "out")).parameter_bytes == Report.read(str(short_job)).parameter_bytes


def test_the_plan_names_the_variables_what_is_static_and_the_cost():
    plan = KIND.plan(SceneRef(get_builtin(SCENE)), CONFIG)
    names = [item.name for item in plan.items]
    assert {v.name for v in get_builtin(SCENE).variables} <= set(names)
    assert "static" in names and plan.estimated_seconds > 0


@pytest.mark.slow
def test_the_network_beats_a_black_renderer_at_every_configuration(tmp_path):
    out = run(tmp_path, KIND.example.overrides)
    report = Report.read(str(out))
    assert report_failures(report) == {}
    source = PatchSource(PatchSourceConfig(SceneRef(get_builtin(SCENE)), CONFIG), SEED)
    vectors = configurations(source.dimensions, CONFIG.evaluation_configurations, SEED)
    tracers = [source.tracer.at(v) for v in vectors]
    size = CONFIG.preview_size
    references = reference_images(tracers, size, CONFIG.reference_spp, CONFIG.max_depth, SEED + 2)
    black = [dssim(r, np.zeros_like(r)) for r in references]
    figures = report.method_metrics
    for i, black_dssim in enumerate(black):
        assert figures[f"configuration_{i}.dssim"] < 0.8 * black_dssim, (i, figures, black)
    assert figures["configurations.mape"] < 0.8 * np.mean([mape(r, np.zeros_like(r)) for r in references])
    assert 0 < figures["exploration.acceptance_rate"] < 1
    assert figures["exploration.final_resolution"] > CONFIG.resolution_start


def test_the_artifact_renders_named_values_and_refuses_bad_ones(short_job, monkeypatch):
    out = short_job
    inference = get_inference("explore")
    loaded = inference.load(out, "cpu")
    params = inference.operations[RENDER].params
    left = loaded.answer(
        RENDER, params(values={"light": [-0.5, 0.0, 0.0]}, camera={"width": 20, "height": 12}), {}
    )
    image = left.arrays["image"]
    assert image.shape == (12, 20, 3) and np.isfinite(image).all() and image.max() > 0
    right = loaded.answer(
        RENDER, params(values={"light": [0.45, 0.0, 0.0]}, camera={"width": 20, "height": 12}), {}
    )
    assert not np.allclose(image, right.arrays["image"])
    normalised = loaded.answer(
        RENDER, params(values={"light": [0.0, 0.5]}, normalised=True, camera={"width": 20, "height": 12}), {}
    )
    np.testing.assert_allclose(normalised.arrays["image"], image, atol=1e-6)
    # antialiased frames (the default, as the report measures) average the pixel centres of a finer frame
    fine = loaded.answer(
        RENDER,
        params(values={"light": [-0.5, 0.0, 0.0]}, camera={"width": 40, "height": 24}, antialiasing=1),
        {},
    )
    two = loaded.answer(
        RENDER,
        params(values={"light": [-0.5, 0.0, 0.0]}, camera={"width": 20, "height": 12}, antialiasing=2),
        {},
    )
    blocks = fine.arrays["image"].reshape(12, 2, 20, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(two.arrays["image"], blocks, rtol=1e-5, atol=1e-6)
    monkeypatch.setattr(evaluate, "PIXELS_PER_CHUNK", 64)  # traced and run in bands of 3 rows
    banded = loaded.answer(
        RENDER,
        params(values={"light": [-0.5, 0.0, 0.0]}, camera={"width": 20, "height": 12}, antialiasing=2),
        {},
    )
    np.testing.assert_allclose(banded.arrays["image"], two.arrays["image"], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"^params\.antialiasing: "):
        loaded.answer(RENDER, params(camera={"width": 4096, "height": 4096}, antialiasing=2), {})
    with pytest.raises(ValueError, match=r"^params\.values\.light: "):
        loaded.answer(RENDER, params(values={"light": [3.0, 0.0, 0.0]}), {})
    with pytest.raises(ValueError, match=r"^params\.values\.nope: "):
        loaded.answer(RENDER, params(values={"nope": 1.0}), {})


def test_a_query_of_the_frames_gbuffers_answers_the_frames_pixels(short_job):
    inference = get_inference("explore")
    loaded = inference.load(short_job, "cpu")
    render_params = inference.operations[RENDER].params
    frame = loaded.answer(
        RENDER, render_params(values={"light": [0.2, 0.8]}, normalised=True, antialiasing=1), {}
    )
    v = np.asarray(frame.meta["v"])
    state = loaded.scene.at(v)
    camera = state.compiled.spec.camera
    buffers = primary_gbuffers(loaded.tracer.state_tracer(state), PinholeCamera(camera))
    n = buffers.hit.size
    arrays = {
        name: getattr(buffers, name).reshape(n, -1).astype(np.float32)
        for name in ("position", "normal", "wo", "albedo", "roughness", "emission")
    }
    arrays["v"] = np.tile(v.astype(np.float32), (n, 1))
    arrays["hit"] = buffers.hit.reshape(n)
    answer = loaded.answer(QUERY, inference.operations[QUERY].params(), arrays)
    np.testing.assert_allclose(
        answer.arrays["radiance"].reshape(frame.arrays["image"].shape),
        frame.arrays["image"],
        rtol=1e-5,
        atol=1e-6,
    )
    with pytest.raises(ValueError, match=r"^arrays\.v: "):
        loaded.answer(QUERY, inference.operations[QUERY].params(), arrays | {"v": arrays["v"][:, :1]})


def test_an_artifact_trained_through_mirrors_serves_frames_through_them(tmp_path):
    """`mirror_bounces` travels with the artifact: served frames are the network's radiance at the
    surfaces the mirrors show, times the mirrors' colour (a query of those buffers, scaled)."""
    overrides = SHORT | {"mirror_bounces": 1}
    _, outcome = run_kind_job("explore", get_builtin("mirror_variable"), tmp_path, overrides, seed=SEED)
    assert outcome.state == "succeeded", outcome.error
    inference = get_inference("explore")
    loaded = inference.load(tmp_path / "out", "cpu")
    size = {"width": 16, "height": 16}
    frame = loaded.answer(RENDER, inference.operations[RENDER].params(camera=size, antialiasing=1), {})
    state = loaded.scene.at(np.asarray(frame.meta["v"]))
    camera = PinholeCamera(state.compiled.spec.camera.model_copy(update=size))
    buffers = primary_gbuffers(loaded.tracer.state_tracer(state), camera, mirror_bounces=1)
    assert (buffers.throughput < 1).any()
    n = buffers.hit.size
    arrays = {
        name: getattr(buffers, name).reshape(n, -1).astype(np.float32)
        for name in ("position", "normal", "wo", "albedo", "roughness", "emission")
    }
    arrays["v"] = np.tile(np.asarray(frame.meta["v"], np.float32), (n, 1))
    arrays["hit"] = buffers.hit.reshape(n)
    radiance = loaded.answer(QUERY, inference.operations[QUERY].params(), arrays).arrays["radiance"]
    expected = (radiance * buffers.throughput.reshape(n, 3)).reshape(frame.arrays["image"].shape)
    np.testing.assert_allclose(frame.arrays["image"], expected, rtol=1e-5, atol=1e-6)
