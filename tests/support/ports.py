"""Ports for the servers and Ray nodes tests start: a free loopback port between Ray's worker ports
(10002-19999) and the kernel's ephemeral range (where Ray's GCS, raylets and agents bind their random
ports), so no Ray node can take it between the test choosing it and its server binding it; or, on a
machine shared by several test runs that were each given a range (`NBAKE_TEST_PORTS=18500-18999`), free
ports of that range only, Ray's worker ports included (Ray's default range would overlap everyone's).
"""

from __future__ import annotations

import os
import random
import socket
from pathlib import Path

RANGE_VARIABLE = "NBAKE_TEST_PORTS"
EPHEMERAL_RANGE = Path("/proc/sys/net/ipv4/ip_local_port_range")
RAY_WORKER_PORTS_END = 19999  # Ray's default --max-worker-port
WORKER_PORTS = 40  # per Ray node: its job drivers, samplers and idle workers, with room to spare

_handed_out: set[int] = set()  # a port given out is not given again, bound or not


def _range() -> range | None:
    value = os.environ.get(RANGE_VARIABLE)
    if not value:
        return None
    low, _, high = value.partition("-")
    return range(int(low), int(high) + 1)


def _below_ephemeral() -> range:
    """The ports above Ray's worker range and below the ephemeral one (empty if they do not exist)."""
    try:
        low = int(EPHEMERAL_RANGE.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return range(0)
    return range(RAY_WORKER_PORTS_END + 1, low)


def _bindable(port: int) -> bool:
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    if _range() is None and not _below_ephemeral():
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            return probe.getsockname()[1]
    return free_block(1)[0]


def free_block(count: int) -> range:
    """`count` consecutive free ports of the assigned range (without one, of the ports below the ephemeral
    range), not given out before."""
    allowed = _range() or _below_ephemeral()
    if not allowed:
        raise LookupError(f"{RANGE_VARIABLE} is not set and no ports lie below the ephemeral range")
    starts = list(range(allowed.start, allowed.stop - count + 1))
    random.shuffle(starts)
    for start in starts:
        block = range(start, start + count)
        if _handed_out.isdisjoint(block) and all(_bindable(port) for port in block):
            _handed_out.update(block)
            return block
    raise LookupError(f"no {count} free consecutive ports left in {allowed.start}-{allowed.stop - 1}")


def worker_port_options() -> list[str]:
    """`ray start` options that keep a node's workers inside the assigned range (none without a range)."""
    if _range() is None:
        return []
    block = free_block(WORKER_PORTS)
    return [f"--min-worker-port={block.start}", f"--max-worker-port={block.stop - 1}"]
