"""Serving an `lsnif` artifact: closest hits of world-space rays against every trained object, placed at
the instances it was trained with.

The artifact holds networks, not the scene around them, so the query reuses the path tracer's
`NeuralIntersector` over an empty triangle set: its broad phase, instance-local rays and one batched
inference call per network are exactly what the renderer runs. Each instance gets an empty triangle
range at its own index, so a hit's `prim` names the instance that was hit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from workers.models.lsnif.artifact import LsnifArtifact, load
from workers.models.lsnif.intersector import NeuralInstance, NeuralIntersector
from workers.models.registry import QUERY, Answer, ArraySpec, Operation


class RayQuery(BaseModel):
    """A ray query has no parameters: the rays are the whole question."""

    model_config = ConfigDict(extra="forbid")


@dataclass(frozen=True)
class _NoTriangles:
    """The part of a compiled scene `NeuralIntersector` reads, for a scene made only of networks."""

    num_triangles: int = 0
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3), np.float32))


class LsnifModel:
    """An artifact's networks on `device`, answering world-space ray queries."""

    def __init__(self, artifact: LsnifArtifact, device: str) -> None:
        self.objects = sorted(artifact.models)
        self.materials = sorted({m for names in artifact.materials.values() for m in names})
        instances, self.instance_object = [], []
        for number, name in enumerate(self.objects):
            model = artifact.models[name].to(device)
            material_ids = np.array([self.materials.index(m) for m in artifact.materials[name]])
            for matrix in artifact.instances[name]:
                index = len(instances)
                instances.append(
                    NeuralInstance(model, model.grid.bounds, matrix, (index, index), material_ids)
                )
                self.instance_object.append(number)
        self.instance_object = np.array(self.instance_object, np.int32)
        self.intersector = NeuralIntersector(_NoTriangles(), instances)
        tensors = [t for m in artifact.models.values() for t in (*m.parameters(), *m.buffers())]
        voxels = sum(m.grid.occupied.nbytes for m in artifact.models.values())
        self.nbytes = sum(t.numel() * t.element_size() for t in tensors) + voxels

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        hits = self.intersector.intersect(arrays["origins"], arrays["directions"])
        hit = hits.found
        instance = np.maximum(hits.prim, 0)
        return Answer(
            arrays={
                "hit": hit,
                "distance": np.where(hit, hits.t, np.inf).astype(np.float32),
                "normal": hits.surface.normal.astype(np.float32),
                "albedo": hits.surface.albedo.astype(np.float32),
                "material": np.where(hit, hits.surface.material, -1).astype(np.int32),
                "object": np.where(hit, self.instance_object[instance], -1).astype(np.int32),
            },
            meta={"materials": self.materials, "objects": self.objects},
        )


class LsnifInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        QUERY: Operation(
            params=RayQuery,
            inputs={
                "origins": ArraySpec("float64", (None, 3)),
                "directions": ArraySpec("float64", (None, 3)),
            },
            batched=True,
        )
    }

    def load(self, folder: Path, device: str) -> LsnifModel:
        return LsnifModel(load(folder), device)


INFERENCE = LsnifInference()
