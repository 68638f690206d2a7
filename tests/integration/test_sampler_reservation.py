"""A sampler pool whose reservation Ray can no longer place (its node left a cluster too small for it)
fails the job as the infrastructure's fault at once instead of waiting forever for a replacement; one
that is placed replaces its dead sampler as before. The multi-node version (the second node's raylet
killed mid-job) is in test_scaleout_cluster.py."""

from __future__ import annotations

import time

import pytest
import ray
from ray.exceptions import RayActorError
from ray.util.placement_group import placement_group, remove_placement_group
from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

from workers.runtime import samplers
from workers.runtime.contract import InfrastructureFailure
from workers.runtime.samplers import SamplerPool
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SourceSpec

SPEC = SourceSpec(AnalyticSource, AnalyticSourceConfig(batch_size=64, samples_per_point=4), seed=1)


def pool_in(group) -> SamplerPool:
    options = {"num_cpus": 1, "scheduling_strategy": PlacementGroupSchedulingStrategy(group)}
    return SamplerPool(SPEC, actors=1, max_in_flight=1, actor_options=options)


def test_a_reservation_the_cluster_cannot_place_fails_the_job_as_infrastructure(ray_cluster, monkeypatch):
    monkeypatch.setattr(samplers, "RESERVATION_REPLACE_S", 1.0)
    cpus = ray.cluster_resources()["CPU"]
    group = placement_group([{"CPU": 1}] * int(cpus + 1), strategy="PACK")  # more than the cluster has
    pool = pool_in(group)
    try:
        with pytest.raises(InfrastructureFailure, match="left the cluster"):
            pool._replace(0)
    finally:
        pool.close()
        remove_placement_group(group)


def wait_until_dead(actor, timeout_s: float = 60.0) -> None:
    """ray.kill only asks for the kill: a call made right after it can still be served by the actor."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            ray.get(actor.produced.remote(), timeout=timeout_s)
        except RayActorError:
            return
        time.sleep(0.05)
    raise AssertionError("the killed sampler actor still answers")


def test_a_placed_reservation_replaces_a_dead_sampler(ray_cluster):
    group = placement_group([{"CPU": 1}], strategy="PACK")
    ray.get(group.ready(), timeout=120)
    with pool_in(group) as pool:
        first = next(pool)
        ray.kill(pool.actors[0], no_restart=True)
        wait_until_dead(pool.actors[0])
        pool.seek(1)  # asks the dead actor again: its batch comes from a replacement
        second = next(pool)
        assert pool.replacements == 1
        assert first.keys() == second.keys()
    remove_placement_group(group)
