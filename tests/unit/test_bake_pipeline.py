"""`nbake bake`'s pieces without a server: gates, the pipeline file (every typo named), the items it
expands to, content digests, the lock file and its diff, the JUnit report, and Retry-After in retries."""

from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree

import pytest
from neuralbake_client.bake import BuildResult, ItemResult
from neuralbake_client.build_lock import BuildLock, LockEntry, diff_locks
from neuralbake_client.durations import seconds
from neuralbake_client.errors import TooManyRequests, Unavailable
from neuralbake_client.gates import Gate, GateError, GateResult
from neuralbake_client.junit import junit_xml
from neuralbake_client.pipeline import PipelineError, content_digest, items, load_pipeline
from neuralbake_client.retry import Retry


@pytest.mark.parametrize(
    ("gate", "metrics", "previous", "passed", "threshold"),
    [
        ("flip <= 0.1", {"flip": 0.08}, None, True, 0.1),
        ("flip <= 0.1", {"flip": 0.12}, None, False, 0.1),
        ("flip<.1", {"flip": 0.1}, None, False, 0.1),
        ("worse_than_one_spp == false", {"worse_than_one_spp": 0.0}, None, True, 0.0),
        ("worse_than_one_spp == false", {"worse_than_one_spp": 1.0}, None, False, 0.0),
        ("psnr >= 2e1", {"psnr": 20.5}, None, True, 20.0),
        ("flip <= previous + 0.01", {"flip": 0.105}, {"flip": 0.1}, True, 0.11),
        ("flip <= previous + 0.01", {"flip": 0.115}, {"flip": 0.1}, False, 0.11),
        ("relative_mse <= previous * 1.1", {"relative_mse": 0.12}, {"relative_mse": 0.1}, False, 0.11),
        ("psnr >= previous - 0.5", {"psnr": 29.6}, {"psnr": 30.0}, True, 29.5),
        ("flip <= previous", {"flip": 0.2}, None, True, None),  # no previous build: passes, says so
    ],
)
def test_gates(gate, metrics, previous, passed, threshold):
    result = Gate.parse(gate).check(metrics, previous)
    assert result.passed is passed
    assert result.threshold == pytest.approx(threshold) if threshold is not None else result.threshold is None
    assert result.note == ("" if threshold is not None else "no previous build to compare")


def test_a_gate_on_a_metric_the_artifact_lacks_fails_and_lists_what_it_has():
    result = Gate.parse("flpi <= 0.1").check({"flip": 0.05, "spp": 4.0}, None)
    assert not result.passed and "flpi" in result.note and "flip, spp" in result.note


@pytest.mark.parametrize(
    "text", ["flip", "flip =< 0.1", "flip <= 0.1 0.2", "<= 0.1", "flip <= prev", "flip <= maybe"]
)
def test_a_gate_that_does_not_parse_shows_the_accepted_forms(text):
    with pytest.raises(GateError, match="METRIC OP NUMBER"):
        Gate.parse(text)


def test_durations():
    assert [seconds(t) for t in ("90", "90s", "1.5m", "2h", 7)] == [90, 90, 90, 7200, 7]
    with pytest.raises(ValueError, match="30m"):
        seconds("ten minutes")


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ("assets: [a]\nkinds: [{kind: render, presett: quick}]\n", "kinds.0.presett: Extra inputs"),
        ("assets: [a]\nkinds: [{kind: render, gates: ['flip < x']}]\n", "kinds.0.gates: Value error, gate"),
        ("assets: [a]\nkinds: [{kind: render}, {kind: render}]\n", "['render'] repeat"),
        ("assets: [{scene: a, kinds: [lod]}]\nkinds: [{kind: render}]\n", "kinds ['lod'] are not in `kinds`"),
        ("assets: [a]\nkinds: [{kind: render}]\ntimeout: soon\n", "timeout: Value error"),
        ("assets: []\nkinds: [{kind: render}]\n", "assets: List should have at least 1 item"),
        ("assets: [a\n", "while parsing"),
    ],
)
def test_a_pipeline_typo_is_named(tmp_path, document, message):
    with pytest.raises(PipelineError, match=r"nbake\.yaml") as error:
        load_pipeline(write(tmp_path / "nbake.yaml", document))
    assert message in str(error.value)


def test_items_cross_assets_with_kinds_expand_globs_once_and_honour_restrictions(tmp_path):
    for name in ("b", "a"):
        write(tmp_path / "assets" / name / "scene.yaml", f"name: {name}\n")
    pipeline = load_pipeline(
        write(
            tmp_path / "nbake.yaml",
            "assets: [cornell_box, 'assets/*', assets/a, {scene: assets/b, kinds: [lod-small]}]\n"
            "kinds: [{kind: render}, {kind: lod, name: lod-small, preset: quick}]\n",
        )
    )
    found = items(pipeline, tmp_path)
    assert [item.name for item in found] == [
        "cornell_box/render",
        "cornell_box/lod-small",
        "assets/a/render",
        "assets/a/lod-small",
        "assets/b/render",
        "assets/b/lod-small",
    ]
    assert found[0].source.path is None and found[2].source.path == tmp_path / "assets" / "a"
    assert found[0].config_digest != found[1].config_digest


def test_a_glob_that_matches_nothing_is_an_error(tmp_path):
    pipeline = load_pipeline(
        write(tmp_path / "nbake.yaml", "assets: ['props/*.glb']\nkinds: [{kind: render}]\n")
    )
    with pytest.raises(PipelineError, match="matches no file"):
        items(pipeline, tmp_path)


def test_a_folder_digest_changes_with_any_content_or_name_and_not_with_time(tmp_path):
    folder = tmp_path / "chair"
    write(folder / "scene.yaml", "name: chair\n")
    write(folder / "meshes" / "seat.obj", "v 0 0 0\n")
    first = content_digest(folder)
    (folder / "meshes" / "seat.obj").touch()
    assert content_digest(folder) == first
    write(folder / "meshes" / "seat.obj", "v 0 0 1\n")
    assert content_digest(folder) != first
    write(folder / "meshes" / "seat.obj", "v 0 0 0\n")
    (folder / "meshes" / "seat.obj").rename(folder / "meshes" / "chair.obj")
    assert content_digest(folder) != first


def entry(artifact: str, **metrics: float) -> LockEntry:
    return LockEntry(
        asset="a",
        kind="render",
        asset_digest="sha256:1",
        config_digest="sha256:2",
        scene="a",
        job_id="job-1",
        artifact_id=artifact,
        metrics=metrics,
    )


def test_the_lock_round_trips_and_a_damaged_one_is_an_error(tmp_path):
    lock = BuildLock(entries={"a/render": entry("sha256:aa", flip=0.1)})
    lock.write(tmp_path / "nbake.lock.json")
    assert BuildLock.read(tmp_path / "nbake.lock.json") == lock
    assert BuildLock.read(tmp_path / "none.json") == BuildLock()
    write(tmp_path / "bad.json", '{"version": 1, "entries": {"a": {}}}')
    with pytest.raises(ValueError, match="not a build lock"):
        BuildLock.read(tmp_path / "bad.json")


def test_diff_names_added_removed_changed_and_same_items_with_their_metrics():
    before = BuildLock(
        entries={"a/render": entry("x", flip=0.2), "b/render": entry("y"), "c/render": entry("z")}
    )
    after = BuildLock(
        entries={"a/render": entry("x2", flip=0.1), "b/render": entry("y"), "d/render": entry("w")}
    )
    changes = {c.name: c for c in diff_locks(before, after)}
    assert {n: c.change for n, c in changes.items()} == {
        "a/render": "changed",
        "b/render": "same",
        "c/render": "removed",
        "d/render": "added",
    }
    assert changes["a/render"].metric_rows() == [("flip", 0.2, 0.1)]


def test_junit_has_a_case_per_item_failures_for_gates_and_errors_for_jobs():
    gate = GateResult(gate="flip <= 0.1", passed=False, value=0.2, threshold=0.1)
    result = BuildResult(
        items=[
            ItemResult(name="a/render", asset="a", kind="render", outcome="passed", metrics={"flip": 0.05}),
            ItemResult(name="b/render", asset="b", kind="render", outcome="gates_failed", gates=[gate]),
            ItemResult(name="c/lod", asset="c", kind="lod", outcome="failed", error="SceneError: no faces"),
        ],
        seconds=3.5,
        lock=BuildLock(),
    )
    root = ElementTree.fromstring(junit_xml(result, "nbake"))
    suite = root.find("testsuite")
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("3", "1", "1")
    cases = {case.get("classname"): case for case in suite.iter("testcase")}
    assert cases["a"].find("failure") is None and "flip = 0.05" in cases["a"].find("system-out").text
    assert cases["b"].find("failure").get("message") == "gates failed: flip <= 0.1"
    assert cases["c"].find("error").get("message") == "SceneError: no faces"
    assert cases["c"].get("name") == "lod"


def test_retries_wait_at_least_what_the_server_asks_and_no_more_than_the_cap(monkeypatch):
    slept = []
    monkeypatch.setattr("neuralbake_client.retry.time.sleep", slept.append)
    answers = iter([TooManyRequests(429, "Too Many Requests", "queued quota", retry_after="3"), "ok"])

    def call():
        answer = next(answers)
        if isinstance(answer, Exception):
            raise answer
        return answer

    retry = Retry(attempts=3, backoff_s=0.1, max_retry_after_s=60)
    assert retry.call(call) == "ok" and slept == [3.0]
    assert Retry(max_retry_after_s=5).wait(0.2, Unavailable(503, "x", "y", retry_after="3600")) == 5
    assert Retry().wait(0.2, Unavailable(503, "x", "y", retry_after="Wed, 21 Oct 2015 07:28:00 GMT")) == 0.2
