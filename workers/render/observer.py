"""Path events of `PathTracer.trace`, for samplers that record what they need along paths.

An observer subclasses `PathObserver` and overrides the events it needs (each default does nothing);
`trace` without an observer skips every call, so observing costs nothing when unused. Arrays passed are
the tracer's own: read them, do not modify them. `idx` names the traced ray (row of `trace`'s input)
each event belongs to.

Escapes carry a weight w such that the environment's share of the traced radiance is
L_env = sum over escapes of w * L_e(direction): w is the path throughput times the MIS weight, for paths
that leave the scene after BSDF sampling and for unblocked light samples of the environment (next-event
estimation) alike. A sampler can therefore relight a path with any environment it has the transfer of
(precomputed radiance transfer) as long as it keeps the scene's environment for importance sampling.
"""

from __future__ import annotations

import numpy as np


class PathObserver:
    def on_surface(self, idx: np.ndarray, position: np.ndarray, normal: np.ndarray, beta: np.ndarray) -> None:
        """Paths reach surface points (N, 3) with shading normals (N, 3) and throughput beta (N, 3)."""

    def on_aggregate(
        self, idx: np.ndarray, position: np.ndarray, voxel: np.ndarray, beta: np.ndarray
    ) -> None:
        """Paths scatter in the aggregate: at its voxels (N, 3) entered at `position`, with throughput
        beta (N, 3) arriving there."""

    def on_escape(self, idx: np.ndarray, directions: np.ndarray, weight: np.ndarray) -> None:
        """Environment light reaches the paths along unit `directions` (N, 3) with weight (N, 3) (module
        docstring)."""
