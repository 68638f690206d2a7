"""The contract every registered kind keeps, checked on its `Example` (the smallest job that exercises it):
a new kind gets these tests by registering.

- its example job runs to success through the driver's `run_job` and leaves files and finite metrics;
- its artifact loads through the inference service's loader (`get_inference`);
- a kind that trains reports its model against path tracing with the shared fields, and is better than
  1-spp path tracing of the same view (a black or NaN model fails here);
- a kind that trains draws batches that are a function of (seed, index) only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from tests.support.jobs import run_kind_job
from tests.support.quality import report_failures
from workers.models.registry import get_inference, get_kind, kind_names
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.contract import JobContext, imported
from workers.runtime.report import PATH_TRACING_SPP, Report
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

SEED = 5
TRAINING_KINDS = [name for name in kind_names() if get_kind(name).method is not None]


@pytest.fixture(scope="module", params=kind_names())
def example_job(request, tmp_path_factory):
    kind = get_kind(request.param)
    folder = tmp_path_factory.mktemp(kind.name)
    scene = get_builtin(kind.example.scene)
    _, outcome = run_kind_job(kind.name, scene, folder, kind.example.overrides, seed=SEED)
    return kind, folder / "out", outcome


def test_the_example_job_succeeds_with_files_and_finite_metrics(example_job):
    _, out, outcome = example_job
    assert outcome.state == "succeeded", outcome.error
    assert outcome.files and all((out / name).is_file() for name in outcome.files)
    assert outcome.metrics and all(math.isfinite(v) for v in outcome.metrics.values()), outcome.metrics


def test_the_artifact_loads_through_the_inference_service(example_job):
    kind, out, _ = example_job
    inference = get_inference(kind.name)
    assert inference is not None and inference.operations, f"{kind.name} registers no inference"
    loaded = inference.load(out, "cpu")
    assert loaded.nbytes > 0


@pytest.mark.parametrize("example_job", TRAINING_KINDS, indirect=True)
def test_a_trained_model_is_reported_against_path_tracing_of_its_view(example_job):
    kind, out, outcome = example_job
    config = kind.resolve_config("quick", kind.example.overrides)
    report = Report.read(str(out))
    assert report.kind == kind.name
    assert [p.label for p in report.path_tracing] == [
        f"{s} spp" for s in PATH_TRACING_SPP if s < config.reference_spp
    ]
    assert report.path_tracing_equal_time in report.path_tracing
    assert report.parameter_bytes > 0 and report.training_samples > 0
    assert {"report.json", "speed_error.png", "preview.png", "reference.png", "frame.png"} <= set(
        outcome.files
    )
    # The preview starts with the reference and ends with the model's frame, both also stored alone.
    preview, reference, frame = (
        np.asarray(Image.open(out / f"{n}.png")) for n in ("preview", "reference", "frame")
    )
    assert reference.shape == frame.shape and preview.shape[0] == reference.shape[0]
    width = reference.shape[1]
    assert np.array_equal(preview[:, :width], reference) and np.array_equal(preview[:, -width:], frame)
    # The quality gate: a model that renders black, NaN or noise worse than one path per pixel fails here.
    assert report_failures(report) == {}
    assert outcome.warnings == [] and outcome.metrics["worse_than_one_spp"] == 0.0


@pytest.mark.parametrize("name", TRAINING_KINDS)
def test_batches_are_a_function_of_seed_and_index(name, tmp_path):
    kind = get_kind(name)
    ctx = JobContext(
        job_id="contract",
        scene=SceneRef(get_builtin(kind.example.scene)),
        config=kind.resolve_config("quick", kind.example.overrides),
        seed=SEED,
        output_dir=tmp_path / "out",
        checkpoints=CheckpointStore(str(tmp_path / "checkpoints")),
    )
    for trainable in imported(kind.method)().trainables(ctx):
        first, second = trainable.source.build(), trainable.source.build()
        again = second.batch(2)
        for key, value in first.batch(2).items():
            assert torch.equal(value, again[key]), f"{name}: batch 2's {key} differs between two builds"
        assert any(not torch.equal(v, first.batch(3)[k]) for k, v in again.items()), "batch 3 repeats batch 2"
