"""Rendering a prefiltered asset at one LoD: the `Aggregate` the path tracer scatters in (Sec. 4.1, 4.5).

A ray walks the level's sparse grid; in every occupied voxel it enters, the visibility network classifies
the segment between entry and exit with that voxel's threshold. An occluded segment is a scattering event
at the entry point with throughput phi from the appearance network; a visible one is passed. Stochastic
traversal: a ray passing a voxel survives with probability max(p, floor) (p the network's probability of
no occlusion) and is reweighted by its inverse, so long walks through nearly empty voxels end early without
bias with respect to the classified visibility. The floor keeps the survival along the grid's diagonal
at the paper's value for 512^3, whatever the resolution.

A ray that starts inside an occupied voxel (a camera or a surface point of the rest of the scene inside
the asset's voxels at this LoD) classifies the segment from its origin to the voxel's exit, a segment
the network never saw in training: a LoD is meant to be seen from outside its voxels.
"""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lod.grid import LodGrid
from workers.models.lod.networks import LodNetworks
from workers.models.lod.sampling import box_exit
from workers.render.aggregate import AggregateEvents
from workers.render.voxels import first_occupied

PAPER_RESOLUTION = 512


def survival_floor(resolution: int, floor_at_512: float) -> float:
    """A per-voxel survival giving the same survival across the diagonal as `floor_at_512` at 512^3."""
    return floor_at_512 ** (PAPER_RESOLUTION / resolution)


class LodAggregate:
    """The asset at LoD `level` as an `Aggregate` (`workers.render.aggregate`)."""

    def __init__(
        self,
        grid: LodGrid,
        networks: LodNetworks,
        level: int,
        optimal_thresholds: bool = True,
        stochastic: bool = True,
        floor_at_512: float = 0.9925,
    ) -> None:
        if not 0 <= level < grid.levels:
            raise ValueError(f"level {level} is not built; this asset has LoDs 0..{grid.levels - 1}")
        self.grid, self.networks, self.level = grid, networks.eval(), level
        self.voxels = grid.level_grid(level)
        self.optimal_thresholds = optimal_thresholds
        self.floor = survival_floor(grid.resolutions[level], floor_at_512) if stochastic else 1.0
        self.device = next(networks.parameters()).device
        self.visibility_queries = 0

    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(array, np.float32)).to(self.device)

    def _p_visible(self, p_o: np.ndarray, p_i: np.ndarray) -> np.ndarray:
        self.visibility_queries += len(p_o)
        with torch.no_grad():
            logits = self.networks.visibility(
                self._tensor(self.grid.normalize(p_o)), self._tensor(self.grid.normalize(p_i))
            )
        return torch.sigmoid(logits).double().cpu().numpy()

    def _thresholds(self, cells: np.ndarray) -> np.ndarray:
        if self.optimal_thresholds:
            return self.grid.threshold(self.level, cells)
        return np.full(len(cells), 0.5)

    def first_events(self, origins, directions, t_min, t_max, rng) -> AggregateEvents:
        return self._walk(origins, directions, t_min, t_max, rng)

    def occluded(self, origins, directions, t_min, t_max) -> np.ndarray:
        """Shadow rays need a yes or no: the same walk without stochastic termination."""
        return self._walk(origins, directions, t_min, t_max, None).found

    def _walk(self, origins, directions, t_min, t_max, rng: np.random.Generator | None) -> AggregateEvents:
        """Classify occupied voxels along every ray until one is occluded; with `rng`, passing a voxel
        is survived with probability max(p, floor) and the survivors are reweighted."""
        n = len(origins)
        events = AggregateEvents(
            np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3), np.int64), np.ones(n)
        )
        rows, t_start = np.arange(n), np.asarray(t_min, np.float64).copy()
        while len(rows):
            o, d = origins[rows], directions[rows]
            walk = first_occupied(self.voxels, o, d, t_start[rows], t_max[rows])
            at = np.flatnonzero(walk.found)
            rows, t_enter, t_exit, cells = rows[at], walk.t_enter[at], walk.t_exit[at], walk.cell[at]
            o, d = o[at], d[at]
            p = self._p_visible(o + t_enter[:, None] * d, o + t_exit[:, None] * d)
            blocked = p < self._thresholds(cells)
            hit = rows[blocked]
            events.found[hit], events.t[hit], events.voxel[hit] = True, t_enter[blocked], cells[blocked]
            passing, t_exit = rows[~blocked], t_exit[~blocked]
            if rng is not None:
                survival = np.maximum(p[~blocked], self.floor)
                alive = rng.random(len(passing)) < survival
                events.weight[passing] = np.where(alive, events.weight[passing] / survival, 0.0)
                passing, t_exit = passing[alive], t_exit[alive]
            rows = passing
            t_start[rows] = t_exit
        return events

    def throughput(self, voxel: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        if len(voxel) == 0:
            return np.zeros((0, 3))
        with torch.no_grad():
            phi = self.networks.appearance(
                self._tensor(self.grid.centres(self.level, voxel)), self._tensor(wo), self._tensor(wi)
            )
        return np.maximum(phi.double().cpu().numpy(), 0.0)

    def exit_distance(self, voxel: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        # The walk's own planes (`VoxelGrid.plane`) and arithmetic: `first_occupied` started at this t
        # leaves the voxel at exactly this t, so a continuing ray never re-enters it for a rounding-length
        # segment (with `grid.boxes`' corners it did for about 6% of random rays).
        return box_exit(self.voxels.plane(voxel), self.voxels.plane(voxel + 1), origins, directions)
