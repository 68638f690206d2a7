"""Sampler actors that keep dying are the cluster's failure for every training kind: the shared pipeline
raises InfrastructureFailure and the driver reports a retryable outcome (the service then retries the job
instead of failing it for good). Shown on `lod`, whose jobs used to fail permanently."""

from __future__ import annotations

import dataclasses
import os

from tests.support.jobs import run_kind_job
from workers.driver import jobs
from workers.models.lod.run import LodMethod
from workers.runtime.pipeline import run_method
from workers.runtime.sources import SourceSpec
from workers.scene.generators.builtin import get_builtin


class DyingLod(LodMethod):
    """The lod method with sampler actors whose process exits on every batch (a node that keeps dying)."""

    def trainables(self, ctx):
        class DyingSource:  # defined here so that Ray ships it by value to the actors
            def __init__(self, config, seed) -> None:
                pass

            def batch(self, index):
                os._exit(1)

        return [
            dataclasses.replace(t, source=SourceSpec(DyingSource, None, ctx.seed))
            for t in super().trainables(ctx)
        ]


def test_a_lod_job_whose_samplers_keep_dying_is_retryable(ray_cluster, tmp_path, monkeypatch):
    def run_dying(kind, ctx):
        assert kind.name == "lod"
        return run_method(DyingLod(), ctx)

    monkeypatch.setattr(jobs, "run_kind", run_dying)
    overrides = {"samplers": 1, "train": {"steps": 5}}
    _, outcome = run_kind_job("lod", get_builtin("menger_sponge"), tmp_path, overrides)
    assert outcome.state == "failed" and outcome.infrastructure_failure, outcome
    assert "sampler actors died" in outcome.error
