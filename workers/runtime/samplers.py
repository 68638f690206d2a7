"""Batch streams: batches in index order, made in-process or by a pool of Ray sampler actors.

Both streams hand out batch i as the i-th item whoever made it, so training does not depend on how many
samplers ran or whether one died. The Ray pool keeps at most `max_in_flight` batches requested but not yet
consumed: a slow trainer stalls the samplers instead of letting results pile up in the object store.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import ray
import torch
from ray.exceptions import GetTimeoutError, ObjectLostError, RayActorError
from ray.util.placement_group import placement_group_table
from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

from workers.runtime.contract import InfrastructureFailure
from workers.runtime.resources import ResourceRequest, actor_options
from workers.runtime.sources import Batch, SourceSpec
from workers.scene.format.errors import SceneError

SAMPLER_FAILURES = (RayActorError, ObjectLostError, GetTimeoutError)
# Samplers that keep dying on one batch (killed, out of memory, a lost node) fail the job as the cluster's
# fault: InfrastructureFailure, which the service retries up to the job's attempts.
REPLACEMENTS_PER_BATCH = 3
# A reservation that lost a node is placed again when the cluster still fits it; one that is not placed
# within this time never will be on the nodes left, so the job restarts (from its checkpoint) on them.
RESERVATION_REPLACE_S = 15.0
RESERVATION_POLL_S = 0.25
# A sampler that neither answers nor dies (a deadlock, a stuck file system) is replaced after waiting this
# long on one batch once it has started, or this long for it to start (import torch, build the source,
# which compiles the scene). Generous: a `paper` batch takes seconds. `NBAKE_BATCH_DEADLINE_S` and
# `NBAKE_SAMPLER_START_DEADLINE_S` override them.
BATCH_DEADLINE_S = float(os.environ.get("NBAKE_BATCH_DEADLINE_S", 300.0))
START_DEADLINE_S = float(os.environ.get("NBAKE_SAMPLER_START_DEADLINE_S", 900.0))


class BatchStream(Protocol):
    """An iterator over batches by index that can be repositioned (for resume)."""

    position: int

    def seek(self, index: int) -> None: ...

    def __next__(self) -> Batch: ...

    def close(self) -> None: ...

    def __enter__(self) -> BatchStream: ...

    def __exit__(self, *exc: object) -> None: ...


class InProcessBatches:
    """Batches made on the caller's thread: the fallback for tests and `quick` runs, and the reference."""

    def __init__(self, spec: SourceSpec, start: int = 0) -> None:
        self.source = spec.build()
        self.position = start

    def seek(self, index: int) -> None:
        self.position = index

    def __iter__(self) -> InProcessBatches:
        return self

    def __next__(self) -> Batch:
        batch = self.source.batch(self.position)
        self.position += 1
        return batch

    def close(self) -> None:
        pass

    def __enter__(self) -> InProcessBatches:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@ray.remote
class SamplerActor:
    """Runs one sample source in its own process; counts what it produced so back-pressure is observable.

    A source that cannot be built from the scene (a texture that does not decode: a SceneError) is the
    user's error, not the cluster's: the actor stays up and every call raises it, so the job fails at once
    naming the file. Raised from `__init__`, Ray would report only that the actor died, and the pool would
    replace it and the service retry the job as a cluster failure."""

    def __init__(self, spec: SourceSpec) -> None:
        self.unusable: SceneError | None = None
        try:
            self.source = spec.build()
        except SceneError as error:
            self.unusable = error
        self.batches_made = 0

    def batch(self, index: int) -> dict[str, np.ndarray]:
        """The batch as NumPy arrays, which Ray moves without pickling (about half the cost of tensors)."""
        self._check_usable()
        self.batches_made += 1
        return {name: tensor.numpy() for name, tensor in self.source.batch(index).items()}

    def render(self, request: Any) -> dict[str, np.ndarray]:
        """What a request-driven source (`RequestSource`) renders for `request`, as NumPy arrays."""
        self._check_usable()
        self.batches_made += 1
        return {name: tensor.numpy() for name, tensor in self.source.render(request).items()}

    def produced(self) -> int:
        self._check_usable()
        return self.batches_made

    def _check_usable(self) -> None:
        if self.unusable is not None:
            raise self.unusable


class SamplerPool:
    """A fixed number of sampler actors feeding batches in index order with a bounded read-ahead.

    Requests go to the actor with the fewest outstanding ones. When fetching a batch reports its actor dead,
    that actor is replaced by a fresh one and every index it still owed is requested again from the new one;
    so is an actor that has not started within START_DEADLINE_S or, once started, has not delivered the
    batch waited on within `batch_deadline_s`.
    """

    def __init__(
        self,
        spec: SourceSpec,
        actors: int = 2,
        max_in_flight: int | None = None,
        actor_options: dict[str, Any] | None = None,
        start: int = 0,
        batch_deadline_s: float = BATCH_DEADLINE_S,
    ) -> None:
        if actors < 1:
            raise ValueError(f"a sampler pool needs at least one actor, got {actors}")
        self.spec = spec
        self.batch_deadline_s = batch_deadline_s
        self.max_in_flight = max_in_flight or 2 * actors
        if self.max_in_flight < 1:
            raise ValueError(f"max_in_flight must be at least 1, got {self.max_in_flight}")
        self.actor_options = actor_options or {"num_cpus": 1}
        self.actors: list[ray.actor.ActorHandle] = []
        self.started: list[ray.ObjectRef] = []  # per slot: resolves once the actor's source is built
        for _ in range(actors):
            self._start_actor(len(self.actors))
        self.replacements = 0
        self.pending: dict[int, tuple[ray.ObjectRef, int]] = {}  # index -> (result, actor slot)
        self.position = start
        self._fill()

    @property
    def in_flight(self) -> int:
        """Batches requested from actors and not yet handed to the consumer."""
        return len(self.pending)

    def _start_actor(self, slot: int) -> None:
        actor = SamplerActor.options(**self.actor_options).remote(self.spec)
        self.actors[slot : slot + 1] = [actor]
        self.started[slot : slot + 1] = [actor.produced.remote()]

    def _request(self, index: int, slot: int) -> None:
        self.pending[index] = (self.actors[slot].batch.remote(index), slot)

    def _least_busy_slot(self) -> int:
        load = [0] * len(self.actors)
        for _, slot in self.pending.values():
            load[slot] += 1
        return min(range(len(self.actors)), key=load.__getitem__)

    def _fill(self) -> None:
        for index in range(self.position, self.position + self.max_in_flight):
            if index not in self.pending:
                self._request(index, self._least_busy_slot())

    def _replace(self, slot: int) -> None:
        self._check_reservation()
        ray.kill(self.actors[slot], no_restart=True)
        self._start_actor(slot)
        self.replacements += 1
        for index in sorted(i for i, (_, s) in self.pending.items() if s == slot):
            self._request(index, slot)

    def _check_reservation(self) -> None:
        """A replacement in a reservation Ray cannot place again (its node left a cluster too small for
        it) would wait forever: InfrastructureFailure instead, so the job restarts sized to the nodes left."""
        strategy = self.actor_options.get("scheduling_strategy")
        if not isinstance(strategy, PlacementGroupSchedulingStrategy):
            return
        deadline = time.monotonic() + RESERVATION_REPLACE_S
        while placement_group_table(strategy.placement_group).get("state") != "CREATED":
            if time.monotonic() > deadline:
                raise InfrastructureFailure(
                    "a node holding the job's sampler actors left the cluster and the nodes left cannot "
                    "hold them all; the job restarts from its checkpoint on the nodes left"
                )
            time.sleep(RESERVATION_POLL_S)

    def seek(self, index: int) -> None:
        self.pending.clear()  # dropped results are freed by Ray once their references are gone
        self.position = index
        self._fill()

    def __iter__(self) -> SamplerPool:
        return self

    def __next__(self) -> Batch:
        for _ in range(REPLACEMENTS_PER_BATCH + 1):
            ref, slot = self.pending[self.position]
            try:
                ray.get(self.started[slot], timeout=START_DEADLINE_S)
                arrays = ray.get(ref, timeout=self.batch_deadline_s)
                break
            except SAMPLER_FAILURES:
                self._replace(slot)
        else:
            raise InfrastructureFailure(
                f"sampler actors died or hung {REPLACEMENTS_PER_BATCH + 1} times making batch "
                f"{self.position}; "
                "check that the sample source can be built and run in a Ray worker"
            )
        del self.pending[self.position]
        self.position += 1
        self._fill()
        # a copy: arrays that Ray hands out are read-only views of its object store
        return {name: torch.tensor(array) for name, array in arrays.items()}

    def close(self) -> None:
        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors, self.started = [], []
        self.pending.clear()

    def __enter__(self) -> SamplerPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_batches(
    spec: SourceSpec,
    samplers: int,
    max_in_flight: int | None = None,
    resources: ResourceRequest | None = None,
    placement: dict[str, Any] | None = None,
    start: int = 0,
) -> BatchStream:
    """Batches from `start` on: a Ray pool of `samplers` actors, or the in-process stream when `samplers` is
    0. Actors are placed by `placement` (Ray options, e.g. a job's reserved slots) or sized by `resources`."""
    if samplers == 0:
        return InProcessBatches(spec, start=start)
    options = placement or actor_options(resources or ResourceRequest())
    return SamplerPool(spec, actors=samplers, max_in_flight=max_in_flight, actor_options=options, start=start)


# ------------------------------------------------------------------ request-driven sources


class Renders(Protocol):
    """Renders a trainer asks for, answered in the order asked (`workers.runtime.sources.RequestSource`)."""

    def map(self, requests: Sequence[Any]) -> list[Batch]: ...

    def close(self) -> None: ...

    def __enter__(self) -> Renders: ...

    def __exit__(self, *exc: object) -> None: ...


class InProcessRenders:
    """Requests rendered on the caller's thread: the fallback without sampler actors, and the reference."""

    def __init__(self, spec: SourceSpec) -> None:
        self.source = spec.build()

    def map(self, requests: Sequence[Any]) -> list[Batch]:
        return [self.source.render(request) for request in requests]

    def close(self) -> None:
        pass

    def __enter__(self) -> InProcessRenders:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RenderPool:
    """Sampler actors rendering requests, at most `max_in_flight` outstanding (back-pressure: a trainer that
    asks for many renders waits instead of filling the object store). A request whose actor died is asked
    again of a replacement, up to `REPLACEMENTS_PER_BATCH` times, then `InfrastructureFailure`."""

    def __init__(
        self,
        spec: SourceSpec,
        actors: int = 2,
        max_in_flight: int | None = None,
        actor_options: dict[str, Any] | None = None,
    ) -> None:
        if actors < 1:
            raise ValueError(f"a render pool needs at least one actor, got {actors}")
        self.spec = spec
        self.max_in_flight = max_in_flight or 2 * actors
        self.actor_options = actor_options or {"num_cpus": 1}
        self.actors = [SamplerActor.options(**self.actor_options).remote(spec) for _ in range(actors)]
        self.replacements = 0

    def map(self, requests: Sequence[Any]) -> list[Batch]:
        results: list[dict[str, np.ndarray] | None] = [None] * len(requests)
        pending: dict[ray.ObjectRef, tuple[int, int, int]] = {}  # ref -> (request, actor slot, attempts)
        next_request = 0
        while next_request < len(requests) or pending:
            while next_request < len(requests) and len(pending) < self.max_in_flight:
                slot = next_request % len(self.actors)
                pending[self.actors[slot].render.remote(requests[next_request])] = (next_request, slot, 0)
                next_request += 1
            [ready], _ = ray.wait(list(pending), num_returns=1)
            index, slot, attempts = pending.pop(ready)
            try:
                results[index] = ray.get(ready)
            except SAMPLER_FAILURES:
                if attempts >= REPLACEMENTS_PER_BATCH:
                    raise InfrastructureFailure(
                        f"sampler actors died {attempts + 1} times rendering one request; "
                        "check that the sample source can be built and run in a Ray worker"
                    ) from None
                ray.kill(self.actors[slot], no_restart=True)
                self.actors[slot] = SamplerActor.options(**self.actor_options).remote(self.spec)
                self.replacements += 1
                pending[self.actors[slot].render.remote(requests[index])] = (index, slot, attempts + 1)
        # copies: arrays that Ray hands out are read-only views of its object store
        return [
            {name: torch.tensor(a) for name, a in result.items()} for result in results if result is not None
        ]

    def close(self) -> None:
        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors = []

    def __enter__(self) -> RenderPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_renders(
    spec: SourceSpec, samplers: int, max_in_flight: int | None = None, placement: dict[str, Any] | None = None
) -> Renders:
    """Renders of a request-driven source by a pool of `samplers` actors, or in process when it is 0."""
    if samplers == 0:
        return InProcessRenders(spec)
    return RenderPool(spec, actors=samplers, max_in_flight=max_in_flight, actor_options=placement)
