"""Test doubles for the `lod` kind."""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lod.grid import LodGrid


class OracleVisibility(torch.nn.Module):
    """A visibility 'network' that answers from the true geometry, with probabilities 0.8 (occluded) and
    0.9 (visible): perfectly separable, and all above a fixed 0.5. `tracer` sees only the asset."""

    def __init__(self, grid: LodGrid, tracer, occluded_p: float = 0.8, visible_p: float = 0.9) -> None:
        super().__init__()
        self.grid, self.tracer = grid, tracer
        self.logits = torch.logit(torch.tensor([occluded_p, visible_p], dtype=torch.float64))
        self.dummy = torch.nn.Parameter(torch.zeros(1))  # callers look up the device of a parameter
        self.calls = 0

    def forward(self, p_o: torch.Tensor, p_i: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        a = self.grid.lo + p_o.double().numpy() * self.grid.extent
        b = self.grid.lo + p_i.double().numpy() * self.grid.extent
        length = np.linalg.norm(b - a, axis=1)
        direction = (b - a) / np.maximum(length, 1e-300)[:, None]
        hits = self.tracer.rays.intersect(a, direction)
        blocked = hits.found & (hits.t < length)
        return self.logits[torch.from_numpy((~blocked).astype(np.int64))].float()
