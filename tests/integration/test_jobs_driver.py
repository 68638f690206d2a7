"""The job driver through a real local Ray cluster: results equal direct renders, cancel, resume, failures."""

import json
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import ray

from workers.driver.jobs import JobHandle, JobOutcome, JobSpec, attach_job, start_job
from workers.models.registry import get_kind
from workers.render.render import RenderSettings, render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import read_exr, read_exr_channels

WAIT_S = 120  # generous: a deadline for a hung test, never a speed assertion


def job_spec(tmp_path, job_id: str, overrides: dict, seed: int = 7, scene: dict | None = None) -> JobSpec:
    config = get_kind("render").resolve_config("quick", overrides)
    return JobSpec(
        job_id=job_id,
        kind="render",
        scene=scene or get_builtin("cornell_box").model_dump(mode="json"),
        config=config.model_dump(mode="json"),
        seed=seed,
        checkpoint_dir=str(tmp_path / "checkpoints"),
        output_dir=str(tmp_path / "output"),
    )


def direct_render(spec: JobSpec):
    """The reference: the path tracer called in-process with the same settings and the job's seed."""
    c = spec.config
    settings = RenderSettings(
        spp=c["spp"],
        width=c["width"],
        height=c["height"],
        max_depth=c["max_depth"],
        rr_depth=c["rr_depth"],
        tile_size=c["tile_size"],
        aovs=c["aovs"],
        seed=spec.seed,
    )
    return render(compile_scene(get_builtin("cornell_box")), settings)


def follow(handle: JobHandle, until=None) -> tuple[JobOutcome | None, list]:
    """Poll events until the outcome arrives (or `until(events)` holds); fails the test if neither does."""
    events = []
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        events += handle.poll()
        if until is not None and until(events):
            return None, events
        outcome = handle.outcome()
        if outcome is not None:
            return outcome, events + handle.poll()
        time.sleep(0.05)
    pytest.fail(f"job {handle.job_id} neither finished nor reached the awaited point; events: {events[-3:]}")


def progress_steps(events) -> list[int]:
    return [e.step for e in events if e.type == "progress"]


@pytest.mark.parametrize("samplers", [3, 0])  # 3 on a 2-CPU cluster: capped to 2, not a deadlock
def test_a_render_job_writes_exactly_the_direct_render(ray_cluster, tmp_path, samplers):
    overrides = {"width": 48, "height": 40, "spp": 12, "samplers": samplers}
    spec = job_spec(tmp_path, f"equal-{samplers}", overrides)
    handle = start_job(spec)
    outcome, events = follow(handle)
    handle.release()

    assert outcome.state == "succeeded", outcome.error
    expected = direct_render(spec)
    np.testing.assert_array_equal(read_exr(outcome.files["image.exr"]), expected.image)
    for name, buffer in expected.aovs.items():
        written = read_exr_channels(outcome.files[f"image.{name}.exr"])
        layer = written.get("RGB", written.get("Y"))
        np.testing.assert_array_equal(layer, buffer if layer.ndim == 3 else buffer[..., 0])
    assert outcome.media_types["image.exr"] == "image/x-exr"
    assert outcome.media_types["preview.png"] == "image/png"
    assert all(path.startswith(spec.output_dir) for path in outcome.files.values())
    report = json.loads(Path(outcome.files["report.json"]).read_text())
    assert (report["width"], report["height"], report["spp"]) == (48, 40, 12)
    assert set(outcome.metrics) >= {"seconds", "rays_per_second", "spp"}
    assert outcome.metrics["rays_per_second"] > 0
    steps = progress_steps(events)
    assert steps and steps[-1] == 12 and steps == sorted(steps)
    assert all(e.total == 12 and e.samples_per_s > 0 for e in events if e.type == "progress")
    if samplers > 2:
        assert any("the cluster fits 2" in (e.message or "") for e in events)


def test_cancel_stops_a_long_render_and_its_samplers(ray_cluster, tmp_path):
    # One sample per pass and 4096 passes: minutes of work, progress after every pass.
    spec = job_spec(tmp_path, "cancel", {"width": 32, "height": 32, "tile_size": 256, "spp": 4096})
    handle = start_job(spec)
    follow(handle, until=progress_steps)
    assert attach_job("cancel") is not None and handle.alive()
    handle.cancel()
    outcome, _ = follow(handle)
    handle.release()

    assert outcome.state == "cancelled"
    assert outcome.error is None and not outcome.infrastructure_failure
    assert not (tmp_path / "output" / "image.exr").exists()
    # Cancelling stopped the samplers too: the cluster's CPUs are all free again.
    deadline = time.monotonic() + WAIT_S
    while ray_cluster.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert ray_cluster.available_resources().get("CPU", 0) == 2


def test_a_restarted_job_resumes_from_its_checkpoint_and_ends_bit_identical(ray_cluster, tmp_path):
    spec = job_spec(tmp_path, "resume", {"width": 32, "height": 32, "tile_size": 256, "spp": 96})
    first = start_job(spec)
    follow(first, until=lambda events: any(step >= 3 for step in progress_steps(events)))
    first.release()  # the driver dies as in a crash, mid-render
    crashed, _ = follow(first)
    assert crashed.state == "failed" and crashed.infrastructure_failure
    assert attach_job("resume") is None

    second = start_job(spec)
    outcome, events = follow(second)
    second.release()

    assert outcome.state == "succeeded", outcome.error
    resumed = [e.message for e in events if e.type == "log" and e.message.startswith("resuming")]
    assert resumed, "the second driver did not resume from the checkpoint"
    passes_done = int(resumed[0].split("after pass ")[1].split()[0])
    assert passes_done >= 3
    assert progress_steps(events)[0] > passes_done
    np.testing.assert_array_equal(read_exr(outcome.files["image.exr"]), direct_render(spec).image)
    report = json.loads(Path(outcome.files["report.json"]).read_text())
    assert report["resumed_after_pass"] == passes_done


def test_a_scene_that_fails_to_compile_fails_the_job_with_one_clear_line(ray_cluster, tmp_path):
    scene = get_builtin("cornell_box").model_dump(mode="json")
    scene["objects"][0]["shape"] = {"type": "mesh", "path": "missing_floor.obj"}
    spec = job_spec(tmp_path, "broken", {}, scene=scene).model_copy(update={"scene_dir": str(tmp_path)})
    handle = start_job(spec)
    outcome, _ = follow(handle)
    handle.release()

    assert outcome.state == "failed"
    assert not outcome.infrastructure_failure
    assert "\n" not in outcome.error
    assert outcome.error.startswith("invalid scene: objects[0].shape")
    assert "missing_floor.obj" in outcome.error


def test_a_config_the_kind_rejects_fails_the_job_naming_the_field(ray_cluster, tmp_path):
    spec = job_spec(tmp_path, "bad-config", {})
    spec = spec.model_copy(update={"config": {**spec.config, "spp": -1}})
    handle = start_job(spec)
    outcome, _ = follow(handle)
    handle.release()

    assert outcome.state == "failed" and not outcome.infrastructure_failure
    assert "spp" in outcome.error and "\n" not in outcome.error


def test_attaching_to_an_unknown_job_finds_nothing(ray_cluster):
    assert attach_job("no-such-job") is None


def scratch_folders(job_id: str) -> list[Path]:
    """The private folders drivers of `job_id` made (on this node, for a job without an output_dir)."""
    return list(Path(tempfile.gettempdir()).glob(f"nbake-{job_id}-p*"))


def uploading_spec(tmp_path, job_id: str, overrides: dict) -> JobSpec:
    """A service's job: the artifact is written to a private folder, then uploaded to the store."""
    spec = job_spec(tmp_path, job_id, overrides)
    return spec.model_copy(
        update={
            "checkpoint_dir": str(tmp_path / job_id / "checkpoints"),
            "output_dir": None,
            "output_url": (tmp_path / job_id / "store").as_uri(),
        }
    )


def test_ending_a_running_driver_removes_its_private_folder(ray_cluster, tmp_path):
    job_id = f"scratch-{uuid.uuid4().hex[:8]}"
    handle = start_job(uploading_spec(tmp_path, job_id, {"width": 32, "height": 32, "spp": 4096}))
    follow(handle, until=progress_steps)
    assert len(scratch_folders(job_id)) == 1
    handle.release()  # as the service ends an abandoned or lost job: its `finally` never runs
    assert scratch_folders(job_id) == []


def test_a_driver_that_died_unannounced_has_its_folder_removed_by_the_next_job(ray_cluster, tmp_path):
    crashed, job_id = f"crash-{uuid.uuid4().hex[:8]}", f"next-{uuid.uuid4().hex[:8]}"
    handle = start_job(uploading_spec(tmp_path, crashed, {"width": 32, "height": 32, "spp": 4096}))
    follow(handle, until=progress_steps)
    ray.kill(handle.actor, no_restart=True)  # a crash: nobody asks it to clean up
    deadline = time.monotonic() + WAIT_S
    while handle.alive() and time.monotonic() < deadline:
        time.sleep(0.05)
    handle.release()  # as the service does once it stored the failure: the driver cannot answer now
    assert len(scratch_folders(crashed)) == 1

    following = start_job(uploading_spec(tmp_path, job_id, {"width": 8, "height": 8, "spp": 1}))
    outcome, _ = follow(following)
    following.release()
    assert outcome.state == "succeeded", outcome.error
    assert scratch_folders(crashed) == [] and scratch_folders(job_id) == []
