"""The inference service's memory pools: a request runs when its bytes fit beside those running, waits in
arrival order otherwise (a large request is not overtaken by small ones), is refused with a 503 and
Retry-After when too many already wait, and gives up with a 503 when nothing frees in time."""

from __future__ import annotations

import threading
import time

import pytest

from services.inference.admission import MemoryPool
from services.inference.errors import Overloaded, QueueFull
from services.inference.metrics import InferenceMetrics

BUDGET = 100


def pool(max_waiting: int = 8) -> MemoryPool:
    return MemoryPool("working", BUDGET, max_waiting, trim_bytes=1 << 40, metrics=InferenceMetrics())


def waiter(memory: MemoryPool, nbytes: int, admitted: list[int]) -> threading.Thread:
    """A thread asking for `nbytes`, returned once it waits in line."""

    def wait() -> None:
        memory.acquire(nbytes, timeout_s=30)
        admitted.append(nbytes)

    before = len(memory.waiting)
    thread = threading.Thread(target=wait, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while len(memory.waiting) == before:
        assert time.monotonic() < deadline, "the request never waited"
        time.sleep(0.001)
    return thread


def test_requests_wait_in_arrival_order_so_a_large_one_is_not_overtaken():
    memory, admitted = pool(), []
    memory.acquire(60, timeout_s=1)
    large = waiter(memory, 80, admitted)
    small = waiter(memory, 10, admitted)  # would fit now (70 of 100), but the large one came first
    time.sleep(0.05)
    assert admitted == [] and memory.used == 60
    memory.release(60)
    large.join(5)
    small.join(5)
    assert admitted == [80, 10] and memory.used == 90


def test_too_many_waiting_is_refused_at_once_with_retry_after():
    memory, admitted = pool(max_waiting=1), []
    memory.acquire(BUDGET, timeout_s=1)
    first = waiter(memory, 50, admitted)
    start = time.monotonic()
    with pytest.raises(QueueFull) as refused:
        memory.acquire(1, timeout_s=30)
    assert time.monotonic() - start < 5  # not after the timeout: at once
    assert refused.value.status == 503 and refused.value.headers == {"Retry-After": "1"}
    memory.release(BUDGET)
    first.join(5)
    assert admitted == [50]


def test_a_request_that_nothing_frees_memory_for_gives_up_after_its_timeout():
    memory = pool()
    memory.acquire(BUDGET, timeout_s=1)
    with pytest.raises(Overloaded):
        memory.acquire(1, timeout_s=0.05)
    assert not memory.waiting and memory.used == BUDGET
