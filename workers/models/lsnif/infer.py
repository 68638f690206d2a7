"""Serving an `lsnif` artifact.

`query`: closest hits of world-space rays against every trained object, placed at the instances it was
trained with. It reuses the path tracer's `NeuralIntersector` over an empty triangle set: its broad
phase, instance-local rays and one batched inference call per network are exactly what the renderer
runs. Each instance gets an empty triangle range at its own index, so a hit's `prim` names the instance
that was hit.

`render`: the trained objects path-traced with LSNIF answering secondary and shadow rays, in the scene
the artifact keeps or alone under a grey sky (`workers.runtime.view_render`). Camera rays go to the
scene's triangles, as the paper rasterises them, when the artifact keeps them, and to the networks
otherwise (`camera_rays`). Without triangles, the networks draw the silhouettes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.models.lsnif.artifact import LsnifArtifact, load
from workers.models.lsnif.intersector import NeuralInstance, NeuralIntersector
from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.render.embree import RayScene
from workers.render.integrator import PathTracer
from workers.render.intersector import Intersector
from workers.runtime.view_render import (
    NEUTRAL,
    RENDER_WORKING_BYTES,
    SCENE,
    ViewRender,
    refuse_missing_scene,
    render_view,
    scene_bytes,
)
from workers.scene.format.spec import Camera, Diffuse, SceneObject, Transform
from workers.scene.geometry.compile import CompiledScene, compile_scene
from workers.scene.geometry.framing import framing_camera
from workers.scene.portability.portable import (
    StoredScene,
    load_scene,
    neutral_scene,
    standin_shape,
)

TRIANGLES, LSNIF = "triangles", "lsnif"
# Working memory of a ray query: the outputs (37 bytes a ray) and their encoded copy; and per ray of a
# chunk, the broad phase's and the networks' intermediates: 8192 rays peaked at 24.5 MB over RSS before
# the call, 65536 at 142 MB (2.05 KB a ray beyond a fixed 7 MB), so 3 KB covers chunks of 8192 and up.
QUERY_ROW_BYTES, QUERY_ACTIVATION_ROW_BYTES = 80, 3 << 10


class RayQuery(BaseModel):
    """A ray query has no parameters: the rays are the whole question."""

    model_config = ConfigDict(extra="forbid")


@dataclass(frozen=True)
class _NoTriangles:
    """The part of a compiled scene `NeuralIntersector` reads, for a scene made only of networks."""

    num_triangles: int = 0
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3), np.float32))


class LsnifRender(ViewRender):
    camera_rays: Literal["triangles", "lsnif"] | None = Field(
        None, description="what answers camera rays; default: the triangles when the artifact keeps them"
    )


@dataclass
class _View:
    """A scene with the networks in it; `triangles` answers camera rays when it holds the objects' own."""

    scene: CompiledScene
    networks: Intersector
    triangles: Intersector | None
    camera: Camera


def _neutral_spec(artifact: LsnifArtifact) -> tuple[list[SceneObject], dict]:
    """The trained objects as stand-ins at their training placements, and their materials."""
    objects = [
        SceneObject(
            name=name,
            shape=standin_shape(model.grid.bounds),
            material=artifact.materials[name][0],
            instances=[Transform(matrix=m.tolist()) for m in artifact.instances[name]],
        )
        for name, model in sorted(artifact.models.items())
    ]
    names = {m for ms in artifact.materials.values() for m in ms}
    return objects, {name: artifact.material_specs.get(name, Diffuse()) for name in sorted(names)}


class LsnifModel:
    """An artifact's networks on `device`, answering world-space ray queries and renders."""

    def __init__(self, artifact: LsnifArtifact, stored: StoredScene, device: str) -> None:
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
        self.stored = stored
        self.views = {NEUTRAL: self._neutral_view(artifact)}
        if stored.spec is not None:
            scene = stored.compiled()
            own = not set(stored.standins) & set(artifact.models)
            triangles = RayScene(scene.positions) if own else None
            self.views[SCENE] = _View(scene, artifact.intersector(scene), triangles, stored.spec.camera)
        tensors = [t for m in artifact.models.values() for t in (*m.parameters(), *m.buffers())]
        voxels = sum(m.grid.occupied.nbytes for m in artifact.models.values())
        scenes = sum(scene_bytes(v.scene) for v in self.views.values())
        self.nbytes = sum(t.numel() * t.element_size() for t in tensors) + voxels + scenes

    def _neutral_view(self, artifact: LsnifArtifact) -> _View:
        scene = compile_scene(neutral_scene(*_neutral_spec(artifact)))
        bounds = np.stack([i.world_bounds for i in self.intersector.instances])
        camera = framing_camera(np.stack([bounds[:, 0].min(0), bounds[:, 1].max(0)]))
        return _View(scene, artifact.intersector(scene), None, camera)

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        if operation == RENDER:
            return self._render(params)
        return self._query(arrays)

    def _render(self, params: LsnifRender) -> Answer:
        if params.background == SCENE:
            refuse_missing_scene(self.stored)
        view = self.views[params.background]
        camera_rays = params.camera_rays or (TRIANGLES if view.triangles is not None else LSNIF)
        if camera_rays == TRIANGLES and view.triangles is None:
            raise ValueError(
                "params.camera_rays: this view holds no triangles of the trained objects (their meshes "
                "are not in the artifact); ask for camera_rays: lsnif"
            )
        primary = view.triangles if camera_rays == TRIANGLES else None
        tracer = PathTracer(view.scene, intersector=view.networks, primary=primary)
        camera = params.camera.over(view.camera)
        return Answer({"image": render_view(tracer, params, camera).image}, {"camera_rays": camera_rays})

    def _query(self, arrays: dict[str, np.ndarray]) -> Answer:
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
            row_bytes=QUERY_ROW_BYTES,
            activation_row_bytes=QUERY_ACTIVATION_ROW_BYTES,
        ),
        RENDER: Operation(params=LsnifRender, call_bytes=RENDER_WORKING_BYTES),
    }

    def load(self, folder: Path, device: str) -> LsnifModel:
        return LsnifModel(load(folder), load_scene(folder), device)


INFERENCE = LsnifInference()
