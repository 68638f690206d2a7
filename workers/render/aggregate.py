"""Aggregate scattering: parts of a scene replaced by voxels that scatter as a whole (levels of detail).

The path tracer asks an `Aggregate` where each ray first scatters in it before the nearest surface, how
much light a scattering voxel sends from one direction into another (`throughput`, which plays the role of
f cos in the rendering equation), and whether it blocks a shadow ray. A ray continuing from a voxel
starts on the voxel's boundary and does not see that voxel again: its transport inside is already in
`throughput` (Weier et al. 2023, Sec. 4.1).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np


@dataclass
class AggregateEvents:
    """Per ray: whether it scatters in the aggregate before t_max, where, and its traversal weight."""

    found: np.ndarray  # (N,) bool
    t: np.ndarray  # (N,) distance to the scattering voxel's entry point (inf where not found)
    voxel: np.ndarray  # (N, 3) int64 index of the scattering voxel where found
    weight: np.ndarray  # (N,) throughput factor of stochastic traversal (0 for a terminated ray)

    def take(self, rows: np.ndarray) -> AggregateEvents:
        return AggregateEvents(*(getattr(self, f.name)[rows] for f in fields(self)))


class Aggregate(Protocol):
    def first_events(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        t_min: np.ndarray,
        t_max: np.ndarray,
        rng: np.random.Generator,
    ) -> AggregateEvents: ...

    def occluded(
        self, origins: np.ndarray, directions: np.ndarray, t_min: np.ndarray, t_max: np.ndarray
    ) -> np.ndarray: ...

    def throughput(self, voxel: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(N, 3) average throughput phi(wo, wi) of voxels (N, 3): wo towards the viewer, wi towards the
        light, both unit world directions."""
        ...

    def exit_distance(self, voxel: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Where rays starting in or on voxels (N, 3) leave them: a continuing ray's t_min."""
        ...
