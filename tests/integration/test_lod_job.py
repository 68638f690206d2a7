"""The `lod` kind end to end through the job driver's `run_job` (no Ray actor): plan, voxelise, train,
thresholds, export, report; then the artifact renders every LoD in the path tracer."""

from __future__ import annotations

import json

import numpy as np

from tests.support.jobs import run_kind_job
from workers.models.lod import artifact
from workers.models.lod.evaluate import lod_tracer
from workers.models.registry import get_kind
from workers.render.render import RenderSettings, render
from workers.scene.builtin import get_builtin
from workers.scene.compile import compile_scene
from workers.scene.reference import SceneRef


def test_quick_lod_job_trains_exports_and_renders(tmp_path):
    kind = get_kind("lod")
    overrides = {"train": {"steps": 20}, "samplers": 0}
    config = kind.resolve_config("quick", overrides)
    scene = get_builtin("menger_sponge")
    scene = scene.model_copy(update={"camera": scene.camera.model_copy(update={"width": 48, "height": 48})})
    plan = kind.plan(SceneRef(scene), config)
    assert [i.choice for i in plan.items[:2]] == ["keep", "prefilter"]  # the ground stays on Embree
    events = []
    _, outcome = run_kind_job("lod", scene, tmp_path, overrides, seed=3, events=events)
    assert outcome.state == "succeeded", outcome.error
    assert {"lod.json", "lod.safetensors", "report.json", "speed_error.png", "preview.png"} <= set(
        outcome.files
    )
    steps = [e.step for e in events if e.type == "progress"]
    assert steps and steps[-1] == 20
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    metrics = report["method_metrics"]
    levels = int(outcome.metrics["levels"])
    assert levels == 3  # 32^3, 16^3, 8^3
    for level in range(levels):
        assert 0.0 <= metrics[f"lod{level}.flip"] < 1.0
        assert metrics[f"lod{level}.mean_path_length"] > 0
    assert all(np.isfinite(v) for v in outcome.metrics.values())

    loaded = artifact.load(tmp_path / "out")
    assert loaded.objects == ["sponge"]
    compiled = compile_scene(scene)
    for level in range(levels):
        tracer = lod_tracer(compiled, loaded, level)
        image = render(tracer, RenderSettings(spp=1, width=12, height=12, threads=1)).image
        assert np.isfinite(image).all() and image.max() > 0
