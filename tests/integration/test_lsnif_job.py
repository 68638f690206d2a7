"""The `lsnif` kind end to end through the job driver's `run_job` (no Ray actor): plan, train, export,
report. The quick preset's object beats trivial baselines (`tests.support.quality`), and an object that
never reports a hit fails every one of those checks; the artifact answers exactly as the trained network;
a job stopped mid-training resumes to the same weights; the networks serve a scene whose instances moved.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.support.jobs import (
    assert_resumes_to_the_uninterrupted_weights,
    progress_steps,
    run_kind_job,
    trained_models,
)
from tests.support.quality import LSNIF_CHECKS, lsnif_failures, prefixed, report_failures
from tests.unit.test_lsnif_model import instanced_scene
from workers.driver.jobs import JobEvent, JobOutcome, JobSpec
from workers.models.lsnif import artifact
from workers.models.lsnif.evaluate import HELD_OUT_SEED, held_out
from workers.models.lsnif.sampling import training_rays
from workers.models.registry import get_kind
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.report import Report
from workers.scene.format.spec import SceneSpec, Transform
from workers.scene.geometry.compile import compile_scene

SEED = 7
OVERRIDES = {"min_triangles": 1000}
CONFIG = get_kind("lsnif").resolve_config("quick", OVERRIDES)
HIT_LOGIT = torch.tensor([0])  # the raw output whose sign says hit


@dataclass
class Job:
    scene: SceneSpec
    folder: Path
    spec: JobSpec
    outcome: JobOutcome
    events: list[JobEvent]

    @property
    def out(self) -> Path:
        return self.folder / "out"


def run(folder: Path, **options) -> Job:
    scene, events = instanced_scene(), []
    spec, outcome = run_kind_job("lsnif", scene, folder, OVERRIDES, seed=SEED, events=events, **options)
    return Job(scene, folder, spec, outcome, events)


@pytest.fixture(scope="module")
def job(tmp_path_factory) -> Job:
    done = run(tmp_path_factory.mktemp("lsnif"))
    assert done.outcome.state == "succeeded", done.outcome.error
    return done


@pytest.fixture(scope="module")
def ball(job):
    """The ball's trainable, holding the weights the artifact was written from."""
    (trainable,) = trained_models(job.spec)
    assert trainable.name == "ball"
    return trainable


def test_quick_lsnif_job_trains_exports_and_reports(job):
    assert {"lsnif.json", "objects/ball.safetensors", "report.json", "speed_error.png", "preview.png"} <= set(
        job.outcome.files
    )
    assert progress_steps(job.events)[-1] == CONFIG.train.steps
    report = Report.read(str(job.out))
    metrics = report.method_metrics
    assert metrics["networks"] == 1 and metrics["ball.instances"] == 2
    assert 0.0 <= metrics["flip_against_embree_same_spp"] < 1.0 and 0.0 < metrics["flip_noise_floor"] < 1.0
    # One network trained: the job's training is the ball's.
    assert report.training_seconds == metrics["ball.training_seconds"] and report.training_samples > 0
    # What the artifact stores: float16 weights, plus the voxel bits and the box.
    loaded = artifact.load(job.out)
    weights = sum(p.numel() for p in loaded.models["ball"].parameters())
    assert report.parameter_bytes == 2 * weights < metrics["ball.model_bytes"] == metrics["model_bytes"]
    # The quick preset's 4-spp LSNIF frame next to Embree at 1 to 64 spp, all against a 256-spp reference.
    assert report.model.label == "4 spp"
    traced = {p.label: p for p in report.path_tracing}
    assert list(traced) == ["1 spp", "4 spp", "16 spp", "64 spp"]
    assert report.path_tracing_equal_time in report.path_tracing
    assert traced["64 spp"].error.relative_mse < traced["4 spp"].error.relative_mse
    assert traced["4 spp"].error.relative_mse < traced["1 spp"].error.relative_mse
    assert all(np.isfinite(v) for v in job.outcome.metrics.values())


def test_the_trained_object_beats_trivial_baselines(job):
    report = Report.read(str(job.out))
    assert lsnif_failures(prefixed(report.method_metrics, "ball")) == {}
    assert report_failures(report) == {}


def test_an_object_that_never_hits_fails_every_check(ball):
    """The fault the old checks passed: "always miss" scored 0.85 occlusion accuracy and no normal error."""
    model = ball.model
    never_hits = model.register_forward_hook(lambda module, inputs, raw: raw.index_fill(1, HIT_LOGIT, -1.0))
    try:
        figures = held_out(model, ball.source.build().prepared, CONFIG.evaluation_rays)
    finally:
        never_hits.remove()
    assert figures.hit_rate == 0.0 and np.isnan(figures.normal_error_deg) and np.isnan(figures.distance_error)
    assert set(lsnif_failures(vars(figures))) == set(LSNIF_CHECKS)


def test_the_artifact_answers_as_the_trained_network(job, ball):
    loaded = artifact.load(job.out).models["ball"]
    for name, value in ball.model.state_dict().items():
        assert np.array_equal(value.numpy(), loaded.state_dict()[name].numpy()), name
    prepared = ball.source.build().prepared
    origins, directions = training_rays(
        prepared.grid, prepared.reference, 4096, np.random.default_rng(HELD_OUT_SEED)
    )
    trained, stored = ball.model.predict(origins, directions), loaded.predict(origins, directions)
    assert trained.hit.any()
    for field in ("hit", "t", "normal", "albedo", "material"):
        np.testing.assert_array_equal(getattr(stored, field), getattr(trained, field), err_msg=field)


def test_a_job_stopped_mid_training_resumes_to_the_uninterrupted_weights(job, tmp_path):
    assert_resumes_to_the_uninterrupted_weights(
        run, job.folder, tmp_path, CONFIG.train, ["checkpoints/ball/{final}", "out/objects/ball.safetensors"]
    )


def test_the_artifact_serves_a_scene_whose_instances_moved(job):
    """The same networks where the instances moved: no retraining, a finite image."""
    scene = job.scene
    ball_object = scene.objects[-1].model_copy(
        update={"instances": [Transform(translate=(0.2, -0.5, 0.0), rotate=(0, 90, 0))]}
    )
    moved = compile_scene(scene.model_copy(update={"objects": [*scene.objects[:-1], ball_object]}))
    embree = PathTracer(moved)
    tracer = PathTracer(moved, intersector=artifact.load(job.out).intersector(moved), primary=embree.rays)
    image = render(tracer, RenderSettings(spp=2, width=16, height=16, threads=1)).image
    assert np.isfinite(image).all() and image.max() > 0
    assert tracer.rays.neural_queries > 0
