"""Sample sources: seeded generators of training batches that any process can rebuild from a spec.

A batch is a pure function of (seed, index). That is what lets a replacement sampler regenerate the
batches a dead one owed, and lets a resumed run continue with exactly the batches it would have seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from pydantic import BaseModel, Field

Batch = dict[str, torch.Tensor]


@runtime_checkable
class SampleSource(Protocol):
    """Produces training batch `index`; the same (config, seed, index) always gives the same batch."""

    def __init__(self, config: Any, seed: int) -> None: ...

    def batch(self, index: int) -> Batch: ...


@runtime_checkable
class RequestSource(Protocol):
    """Renders what a trainer asks for (a trainer that chooses its samples, such as active exploration):
    `render(request)` is a pure function of the request, which carries its own seed, so any process
    renders the same batch for it and a dead sampler's requests can be asked of another."""

    def __init__(self, config: Any, seed: int) -> None: ...

    def render(self, request: Any) -> Batch: ...


@dataclass(frozen=True)
class SourceSpec:
    """Everything a sampler process needs to rebuild a source: an importable class, its config, a seed."""

    source: type[SampleSource]
    config: Any
    seed: int

    def build(self) -> SampleSource:
        return self.source(self.config, self.seed)


def batch_rng(seed: int, index: int) -> np.random.Generator:
    """The random stream of one batch, independent of every other batch and of who computes it."""
    if seed < 0 or index < 0:
        raise ValueError(f"seed and batch index must be non-negative, got seed={seed}, index={index}")
    return np.random.default_rng([seed, index])


class AnalyticSourceConfig(BaseModel):
    """Size and cost of the analytic source; `samples_per_point` plays the role of spp in a path tracer."""

    batch_size: int = Field(1024, ge=1)
    input_dim: int = Field(3, ge=1)
    output_dim: int = Field(3, ge=1)
    samples_per_point: int = Field(4, ge=1)
    frequency: float = Field(1.0, gt=0)


class AnalyticSource:
    """Monte Carlo estimates of a known smooth function, noisy like path-traced radiance.

    Target j at point x is the integral over u in [0, 1] of 2u (1 + sin(2 pi f x.w_j + phi_j)), whose exact
    value is 1 + sin(2 pi f x.w_j + phi_j); each estimate averages `samples_per_point` uniform u. The
    directions w_j and phases phi_j come from the seed, so the function is fixed for a source.
    """

    def __init__(self, config: AnalyticSourceConfig, seed: int) -> None:
        self.config = config
        self.seed = seed
        function_rng = np.random.default_rng([seed, 2**31])
        directions = function_rng.normal(size=(config.input_dim, config.output_dim))
        self.directions = directions / np.linalg.norm(directions, axis=0, keepdims=True)
        self.phases = function_rng.uniform(0.0, 2.0 * math.pi, size=config.output_dim)

    def expected(self, points: np.ndarray) -> np.ndarray:
        """The exact function value the estimates converge to."""
        angle = 2.0 * math.pi * self.config.frequency * (points @ self.directions) + self.phases
        return 1.0 + np.sin(angle)

    def batch(self, index: int) -> Batch:
        c = self.config
        rng = batch_rng(self.seed, index)
        points = rng.uniform(0.0, 1.0, size=(c.batch_size, c.input_dim))
        u = rng.uniform(0.0, 1.0, size=(c.batch_size, c.output_dim, c.samples_per_point))
        estimates = self.expected(points) * (2.0 * u).mean(axis=2)
        return {
            "inputs": torch.from_numpy(points.astype(np.float32)),
            "targets": torch.from_numpy(estimates.astype(np.float32)),
        }
