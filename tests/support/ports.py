"""Ports for the servers and Ray nodes tests start: any free loopback port, or, on a machine shared by
several test runs that were each given a range (`NBAKE_TEST_PORTS=18500-18999`), free ports of that range
only, Ray's worker ports included (Ray's own default range, 10002-19999, would overlap everyone's).
"""

from __future__ import annotations

import os
import random
import socket

RANGE_VARIABLE = "NBAKE_TEST_PORTS"
WORKER_PORTS = 40  # per Ray node: its job drivers, samplers and idle workers, with room to spare

_handed_out: set[int] = set()  # within a range, a port given out is not given again before it is bound


def _range() -> range | None:
    value = os.environ.get(RANGE_VARIABLE)
    if not value:
        return None
    low, _, high = value.partition("-")
    return range(int(low), int(high) + 1)


def _bindable(port: int) -> bool:
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    allowed = _range()
    if allowed is None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            return probe.getsockname()[1]
    return free_block(1)[0]


def free_block(count: int) -> range:
    """`count` consecutive free ports of the assigned range, not given out before."""
    allowed = _range()
    if allowed is None:
        raise LookupError(f"{RANGE_VARIABLE} is not set: no range to take a block from")
    starts = list(range(allowed.start, allowed.stop - count + 1))
    random.shuffle(starts)
    for start in starts:
        block = range(start, start + count)
        if _handed_out.isdisjoint(block) and all(_bindable(port) for port in block):
            _handed_out.update(block)
            return block
    raise LookupError(
        f"no {count} free consecutive ports left in {RANGE_VARIABLE}={os.environ[RANGE_VARIABLE]}"
    )


def worker_port_options() -> list[str]:
    """`ray start` options that keep a node's workers inside the assigned range (none without a range)."""
    if _range() is None:
        return []
    block = free_block(WORKER_PORTS)
    return [f"--min-worker-port={block.start}", f"--max-worker-port={block.stop - 1}"]
