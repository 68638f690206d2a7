"""Torch's intra-op thread count for a block of code."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run a block with `count` intra-op threads in torch. Renders that call small networks from several
    render threads at once need 1: with more, torch's workers oversubscribe the cores and busy-wait
    (measured 15x slower on 2 loaded cores)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
