"""The `lsnif` kind end to end through the job driver's `run_job` (no Ray actor): plan, train, export,
report, then load the artifact into a path tracer for a scene whose instances moved."""

from __future__ import annotations

import numpy as np

from tests.support.jobs import run_kind_job
from tests.unit.test_lsnif_model import instanced_scene
from workers.models.lsnif import artifact
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.report import Report
from workers.scene.compile import compile_scene
from workers.scene.spec import Transform


def test_quick_lsnif_job_trains_exports_and_renders(tmp_path):
    scene = instanced_scene()
    events = []
    overrides = {"min_triangles": 1000, "train": {"steps": 30}}
    _, outcome = run_kind_job("lsnif", scene, tmp_path, overrides, seed=7, events=events)
    assert outcome.state == "succeeded", outcome.error
    assert {"lsnif.json", "objects/ball.safetensors", "report.json", "speed_error.png", "preview.png"} <= set(
        outcome.files
    )
    steps = [e.step for e in events if e.type == "progress"]
    assert steps and steps[-1] == 30
    report = Report.read(str(tmp_path / "out"))
    metrics = report.method_metrics
    assert metrics["networks"] == 1 and metrics["ball.instances"] == 2
    assert 0.5 < metrics["ball.occlusion_accuracy"] <= 1.0
    assert 0.0 <= metrics["flip_against_embree_same_spp"] < 1.0 and 0.0 < metrics["flip_noise_floor"] < 1.0
    # One network trained: the job's training is the ball's.
    assert report.training_seconds == metrics["ball.training_seconds"] and report.training_samples > 0
    # What the artifact stores: float16 weights, plus the voxel bits and the box.
    loaded = artifact.load(tmp_path / "out")
    weights = sum(p.numel() for p in loaded.models["ball"].parameters())
    assert report.parameter_bytes == 2 * weights < metrics["ball.model_bytes"] == metrics["model_bytes"]
    # The quick preset's 4-spp LSNIF frame next to Embree at 1 to 64 spp, all against a 256-spp reference.
    assert report.model.label == "4 spp" and 0.0 < report.model.error.flip < 1.0
    traced = {p.label: p for p in report.path_tracing}
    assert list(traced) == ["1 spp", "4 spp", "16 spp", "64 spp"]
    assert report.path_tracing_equal_time in report.path_tracing
    assert traced["64 spp"].error.relative_mse < traced["4 spp"].error.relative_mse
    assert traced["4 spp"].error.relative_mse < traced["1 spp"].error.relative_mse
    assert all(np.isfinite(v) for v in outcome.metrics.values())

    # The same networks in a scene where the instances moved: no retraining, a finite image.
    ball_object = scene.objects[-1].model_copy(
        update={"instances": [Transform(translate=(0.2, -0.5, 0.0), rotate=(0, 90, 0))]}
    )
    moved = compile_scene(scene.model_copy(update={"objects": [*scene.objects[:-1], ball_object]}))
    embree = PathTracer(moved)
    tracer = PathTracer(moved, intersector=loaded.intersector(moved), primary=embree.rays)
    image = render(tracer, RenderSettings(spp=2, width=16, height=16, threads=1)).image
    assert np.isfinite(image).all() and image.max() > 0
    assert tracer.rays.neural_queries > 0
