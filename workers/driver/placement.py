"""Sampler actors reserved as one gang: a job starts only when all its samplers fit, or none.

Starting actors one by one lets two jobs each hold part of the cluster while waiting for the rest, and a
pool that hands items to a sampler Ray cannot place waits forever. A placement group reserves every
sampler's CPU at once; the wait for it can be cancelled; and a request larger than the whole cluster is
capped to it, since results never depend on how many samplers made them.

The group is named after the job: Ray scopes it to the service's process, not to the driver actor, so a
driver that died leaves it behind; the job's next driver, or the service releasing the job, removes it.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Iterator

import ray
from ray.util.placement_group import get_placement_group, placement_group, remove_placement_group
from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

from workers.runtime.contract import JobCancelled, SamplerSlots

READY_POLL_S = 0.5


def group_name(job_id: str) -> str:
    return f"nbake-job-{job_id}-samplers"


def remove_reservation(job_id: str) -> None:
    """Remove the job's sampler reservation, if one is left (killing any actor still in it)."""
    with contextlib.suppress(ValueError):  # none left
        remove_placement_group(get_placement_group(group_name(job_id)))


def sampler_reserver(
    job_id: str, cpus_each: float, cancel: threading.Event, log: Callable[[str], None]
) -> Callable[[int], contextlib.AbstractContextManager[SamplerSlots]]:
    """`reserve(count)` for a JobContext: reserves `count` sampler slots while the `with` block runs."""

    @contextlib.contextmanager
    def reserve(count: int) -> Iterator[SamplerSlots]:
        if count <= 0:
            yield SamplerSlots(count=0, actor_options={"num_cpus": cpus_each})
            return
        fits = max(1, math.floor(ray.cluster_resources().get("CPU", 0) / cpus_each))
        if count > fits:
            log(f"{count} samplers asked for, the cluster fits {fits}: using {fits}")
            count = fits
        remove_reservation(job_id)  # left by an earlier driver of this job that died
        group = placement_group([{"CPU": cpus_each}] * count, strategy="PACK", name=group_name(job_id))
        try:
            while not ray.wait([group.ready()], timeout=READY_POLL_S)[0]:
                if cancel.is_set():
                    raise JobCancelled("cancelled while waiting for the cluster to fit the samplers")
            strategy = PlacementGroupSchedulingStrategy(group)
            yield SamplerSlots(count, {"num_cpus": cpus_each, "scheduling_strategy": strategy})
        finally:
            remove_placement_group(group)

    return reserve
