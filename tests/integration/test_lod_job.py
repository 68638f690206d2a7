"""The `lod` kind end to end through the job driver's `run_job` (no Ray actor): plan, voxelise, train,
thresholds, export, report. Every LoD of the quick preset's asset beats trivial baselines
(`tests.support.quality`), and a black asset fails every one of those checks; the artifact answers exactly
as the trained networks; a job stopped mid-training resumes to the same weights; every LoD renders in the
path tracer.
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
from tests.support.quality import LOD_CHECKS, asset_radiance, lod_failures, prefixed, report_failures
from workers.driver.jobs import JobEvent, JobOutcome, JobSpec
from workers.models.lod import artifact
from workers.models.lod.evaluate import evaluate_levels, lod_tracer
from workers.models.registry import get_kind
from workers.render.render import RenderSettings, render
from workers.runtime.report import Report
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.reference import SceneRef

SEED = 3
OVERRIDES = {"samplers": 0}
CONFIG = get_kind("lod").resolve_config("quick", OVERRIDES)
LEVELS = 3  # 32^3, 16^3, 8^3


def sponge():
    scene = get_builtin("menger_sponge")
    return scene.model_copy(update={"camera": scene.camera.model_copy(update={"width": 48, "height": 48})})


@dataclass
class Job:
    folder: Path
    spec: JobSpec
    outcome: JobOutcome
    events: list[JobEvent]

    @property
    def out(self) -> Path:
        return self.folder / "out"


def run(folder: Path, **options) -> Job:
    events = []
    spec, outcome = run_kind_job("lod", sponge(), folder, OVERRIDES, seed=SEED, events=events, **options)
    return Job(folder, spec, outcome, events)


@pytest.fixture(scope="module")
def job(tmp_path_factory) -> Job:
    done = run(tmp_path_factory.mktemp("lod"))
    assert done.outcome.state == "succeeded", done.outcome.error
    return done


@pytest.fixture(scope="module")
def scene():
    return compile_scene(sponge())


def level_figures(figures: dict[str, float], scene, asset, level: int) -> dict[str, float]:
    """A level's figures as the job reported them (`figures`: its method_metrics), with the radiance."""
    return {**prefixed(figures, f"lod{level}"), **asset_radiance(scene, asset, level, SEED)}


def test_quick_lod_job_trains_exports_and_reports(job):
    plan = get_kind("lod").plan(SceneRef(sponge()), CONFIG)
    assert [i.choice for i in plan.items[:2]] == ["keep", "prefilter"]  # the ground stays on Embree
    assert {"lod.json", "lod.safetensors", "report.json", "speed_error.png", "preview.png"} <= set(
        job.outcome.files
    )
    assert progress_steps(job.events)[-1] == CONFIG.train.steps
    assert int(job.outcome.metrics["levels"]) == LEVELS
    assert artifact.load(job.out).objects == ["sponge"]
    assert all(np.isfinite(v) for v in job.outcome.metrics.values())


def test_every_level_beats_trivial_baselines(job, scene):
    report = Report.read(str(job.out))
    asset = artifact.load(job.out)
    for level in range(LEVELS):
        assert lod_failures(level_figures(report.method_metrics, scene, asset, level)) == {}, f"LoD {level}"
    assert report_failures(report) == {}


def test_a_black_asset_fails_every_check(job, scene):
    """The fault the old checks passed: the appearance output times 0 (FLIP < 1, a lit ground and sky, and
    paths of length > 0 all held for it)."""
    asset = artifact.load(job.out)
    asset.networks.appearance.register_forward_hook(lambda module, inputs, phi: phi * 0)
    measured = evaluate_levels(scene, asset, SEED)
    for figures in measured.figures:
        reported = {f"lod{figures.level}.{k}": v for k, v in figures.model_dump().items()}
        failures = lod_failures(level_figures(reported, scene, asset, figures.level))
        assert set(failures) == set(LOD_CHECKS), f"LoD {figures.level}: {failures}"


def test_the_artifact_answers_as_the_trained_networks(job):
    (trained,) = trained_models(job.spec)
    loaded = artifact.load(job.out).networks
    for name, value in trained.model.state_dict().items():
        assert torch.equal(value, loaded.state_dict()[name]), name
    generator = torch.Generator().manual_seed(0)
    points, directions = (
        torch.rand(4, 4096, 3, generator=generator),
        torch.randn(2, 4096, 3, generator=generator),
    )
    wo, wi = directions / directions.norm(dim=-1, keepdim=True)

    @torch.no_grad()
    def answers(networks):
        return networks.appearance(points[0], wo, wi), networks.visibility(points[1], points[2])

    for ours, theirs in zip(answers(trained.model), answers(loaded), strict=True):
        assert torch.equal(ours, theirs)


def test_a_job_stopped_mid_training_resumes_to_the_uninterrupted_weights(job, tmp_path):
    assert_resumes_to_the_uninterrupted_weights(
        run, job.folder, tmp_path, CONFIG.train, ["checkpoints/{final}", "out/lod.safetensors"]
    )


def test_every_level_renders_in_the_path_tracer(job, scene):
    loaded = artifact.load(job.out)
    for level in range(LEVELS):
        image = render(
            lod_tracer(scene, loaded, level), RenderSettings(spp=1, width=12, height=12, threads=1)
        )
        assert np.isfinite(image.image).all() and image.image.max() > 0
