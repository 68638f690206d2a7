"""Repeated submissions of the same work are cheap and answer the same job: found by the load bench, a
repeat used to be validated, resolved and planned again before the database said it existed."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from services.api.services import Services
from services.api.settings import ServiceSettings
from services.jobs.submission import JobRequest


@pytest.fixture
def services(tmp_path):
    built = Services.build(ServiceSettings(data_dir=tmp_path, tokens="t:admin", scheduling=False))
    built.start()
    try:
        yield built
    finally:
        built.stop()


def test_ten_repeats_answer_one_job_planned_once(services, monkeypatch):
    planned = []
    plan = services.submitter._checked_plan
    monkeypatch.setattr(services.submitter, "_checked_plan", lambda *a: planned.append(a) or plan(*a))
    request = JobRequest(kind="render", scene="cornell_box", preset="quick", seed=3)
    answers = [services.submit(request) for _ in range(10)]
    assert len({job.id for job, _ in answers}) == 1
    assert [created for _, created in answers] == [True] + [False] * 9
    assert len(planned) == 1  # the repeats were answered before planning
    other = services.submit(request.model_copy(update={"seed": 4}))[0]
    assert other.id != answers[0][0].id and len(planned) == 2
    forced = services.submit(request.model_copy(update={"force": True}))[0]
    assert forced.id != answers[0][0].id  # force makes a new job of the same work


def test_identical_new_submissions_in_one_process_insert_once(services, monkeypatch):
    """The first of several identical new submissions creates the job; the others of the same process wait
    for it and read it, instead of each inserting a job that loses on the key and is rolled back."""
    inserts = []
    create = services.jobs.create
    raced = threading.Event()

    def lingering_create(*args, **kwargs):  # the first insert waits a while for others to race it
        inserts.append(args[0].id)
        if len(inserts) == 1:
            raced.wait(1.0)
        else:
            raced.set()
        return create(*args, **kwargs)

    monkeypatch.setattr(services.jobs, "create", lingering_create)
    request = JobRequest(kind="render", scene="cornell_box", preset="quick", seed=5)
    with ThreadPoolExecutor(6) as pool:
        answers = list(pool.map(lambda _: services.submit(request), range(6)))
    assert len({job.id for job, _ in answers}) == 1
    assert sorted(created for _, created in answers) == [False] * 5 + [True]
    assert len(inserts) == 1


def test_a_resolved_scene_is_reused_and_inline_scenes_are_keyed_by_content(services):
    scenes = services.scenes
    assert scenes.resolve("cornell_box") is scenes.resolve("cornell_box")
    inline = scenes.resolve("cornell_box").spec_json
    reordered = dict(reversed(list(inline.items())))
    assert scenes.resolve(inline) is scenes.resolve(reordered)  # same content, same resolution
    assert scenes.resolve(inline).content_hash == scenes.resolve("cornell_box").content_hash
