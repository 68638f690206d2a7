"""Serving a `lod` artifact: where world-space rays first scatter in the asset at a chosen LoD, and, given
incident directions, the prefiltered throughput phi(w_o, w_i) of the voxel they scatter in.

That is what a renderer needs to use the LoD in place of the asset (`traversal.LodAggregate` is the same
code the path tracer runs); traversal here is deterministic (no stochastic termination), so the answer
for a ray does not depend on the batch it was merged into.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from workers.models.lod.artifact import LodAsset, load
from workers.models.registry import QUERY, Answer, ArraySpec, Operation


class LodQuery(BaseModel):
    model_config = ConfigDict(extra="forbid")

    level: int = Field(0, ge=0, description="the LoD to trace against (0 = finest built)")
    optimal_thresholds: bool = True


class LodModel:
    def __init__(self, asset: LodAsset, device: str) -> None:
        self.asset = asset
        asset.networks.to(device)
        self.nbytes = asset.network_bytes() + asset.grid.storage_bytes()

    def answer(self, operation: str, params: LodQuery, arrays: dict[str, np.ndarray]) -> Answer:
        if params.level >= self.asset.grid.levels:
            raise ValueError(f"params.level: this artifact has LoDs 0..{self.asset.grid.levels - 1}")
        aggregate = self.asset.aggregate(params.level, params.optimal_thresholds, stochastic=False)
        origins, directions = arrays["origins"], arrays["directions"]
        directions = directions / np.maximum(np.linalg.norm(directions, axis=1, keepdims=True), 1e-300)
        n = len(origins)
        with torch.inference_mode():
            events = aggregate.first_events(
                origins, directions, np.zeros(n), np.full(n, np.inf), np.random.default_rng(0)
            )
            out = {
                "hit": events.found,
                "distance": np.where(events.found, events.t, np.inf).astype(np.float32),
                "voxel": np.where(events.found[:, None], events.voxel, -1).astype(np.int32),
            }
            if "incident" in arrays:
                phi = np.zeros((n, 3))
                at = np.flatnonzero(events.found)
                wi = arrays["incident"][at]
                wi = wi / np.maximum(np.linalg.norm(wi, axis=1, keepdims=True), 1e-300)
                phi[at] = aggregate.throughput(events.voxel[at], -directions[at], wi)
                out["throughput"] = phi.astype(np.float32)
        return Answer(arrays=out, meta={"resolution": self.asset.grid.resolutions[params.level]})


class LodInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        QUERY: Operation(
            params=LodQuery,
            inputs={
                "origins": ArraySpec("float64", (None, 3)),
                "directions": ArraySpec("float64", (None, 3)),
                "incident": ArraySpec("float64", (None, 3), required=False),
            },
            batched=True,
        )
    }

    def load(self, folder: Path, device: str) -> LodModel:
        return LodModel(load(folder), device)


INFERENCE = LodInference()
