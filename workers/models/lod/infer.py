"""Serving a `lod` artifact.

`query`: where world-space rays first scatter in the asset at a chosen LoD, and, given incident
directions, the prefiltered throughput phi(w_o, w_i) of the voxel they scatter in. That is what a renderer
needs to use the LoD in place of the asset (`traversal.LodAggregate` is the same code the path tracer
runs); traversal here is deterministic (no stochastic termination), so the answer for a ray does not
depend on the batch it was merged into.

`render`: the asset at a LoD, path-traced in the scene the artifact keeps or alone under a grey sky
(`workers.runtime.view_render`). Without `level`, the LoD is the one whose voxel is about a pixel at the
camera's distance from the asset, as `plan` chooses LoDs for `view_distances`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from workers.models.lod.artifact import LodAsset, load
from workers.models.lod.plan import resolution_at
from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.render.embree import SubsetRayScene
from workers.render.integrator import PathTracer
from workers.runtime.view_render import (
    NEUTRAL,
    RENDER_WORKING_BYTES,
    SCENE,
    ViewRender,
    refuse_missing_scene,
    render_view,
    scene_bytes,
)
from workers.scene.format.spec import Camera, Diffuse, SceneObject
from workers.scene.geometry.compile import CompiledScene, compile_scene
from workers.scene.geometry.framing import framing_camera
from workers.scene.portability.portable import (
    StoredScene,
    load_scene,
    neutral_scene,
    standin_shape,
)

STANDIN = "lod asset"
# Working memory of a ray query: the outputs (at most 29 bytes a ray) and their encoded copy; per ray of a
# chunk, the traversal's and the throughput network's intermediates: 8192 rays with `incident` peaked at
# 19.8 MB over RSS before the call, 65536 at 124 MB (1.8 KB a ray beyond a fixed 5 MB).
QUERY_ROW_BYTES, QUERY_ACTIVATION_ROW_BYTES = 64, 5 << 9


class LodQuery(BaseModel):
    model_config = ConfigDict(extra="forbid")

    level: int = Field(0, ge=0, description="the LoD to trace against (0 = finest built)")
    optimal_thresholds: bool = True


class LodRender(ViewRender):
    level: int | None = Field(
        None, ge=0, description="the LoD (0 = finest built); default: a voxel is about a pixel"
    )
    optimal_thresholds: bool = True


@dataclass
class _View:
    """A scene to render the asset in: its triangles other than the asset's, and its default camera."""

    scene: CompiledScene
    others: SubsetRayScene
    camera: Camera


def _view(scene: CompiledScene, asset_objects: list[str], camera: Camera) -> _View:
    asset = [o.index for o in scene.objects if o.name in asset_objects]
    others = np.flatnonzero(~np.isin(scene.object_ids, asset))
    return _View(scene, SubsetRayScene(scene.positions, others), camera)


class LodModel:
    def __init__(self, asset: LodAsset, stored: StoredScene, device: str) -> None:
        self.asset, self.stored = asset, stored
        asset.networks.to(device)
        grid = asset.grid
        self.bounds = np.stack([grid.lo, grid.lo + grid.extent])
        neutral = neutral_scene(
            [SceneObject(name=STANDIN, shape=standin_shape(self.bounds), material=STANDIN)],
            {STANDIN: Diffuse()},
        )
        self.views = {NEUTRAL: _view(compile_scene(neutral), [STANDIN], framing_camera(self.bounds))}
        if stored.spec is not None:
            self.views[SCENE] = _view(stored.compiled(), list(stored.standins), stored.spec.camera)
        scenes = sum(scene_bytes(v.scene) for v in self.views.values())
        self.nbytes = asset.network_bytes() + grid.storage_bytes() + scenes

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        if operation == RENDER:
            return self._render(params)
        return self._query(params, arrays)

    def _checked_level(self, level: int) -> int:
        if level >= self.asset.grid.levels:
            raise ValueError(f"params.level: this artifact has LoDs 0..{self.asset.grid.levels - 1}")
        return level

    def level_for(self, camera: Camera) -> int:
        """The LoD whose voxel is about one pixel of `camera` at its distance from the asset's centre."""
        grid = self.asset.grid
        distance = float(np.linalg.norm(self.bounds.mean(0) - np.asarray(camera.position)))
        return grid.resolutions.index(resolution_at(camera, distance, grid.extent, grid.resolutions))

    def _render(self, params: LodRender) -> Answer:
        if params.background == SCENE:
            refuse_missing_scene(self.stored)
        view = self.views[params.background]
        camera = params.camera.over(view.camera)
        level = self.level_for(camera) if params.level is None else self._checked_level(params.level)
        aggregate = self.asset.aggregate(level, params.optimal_thresholds)
        tracer = PathTracer(view.scene, intersector=view.others, aggregate=aggregate)
        image = render_view(tracer, params, camera).image
        return Answer({"image": image}, {"level": level, "resolution": self.asset.grid.resolutions[level]})

    def _query(self, params: LodQuery, arrays: dict[str, np.ndarray]) -> Answer:
        self._checked_level(params.level)
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
            row_bytes=QUERY_ROW_BYTES,
            activation_row_bytes=QUERY_ACTIVATION_ROW_BYTES,
        ),
        RENDER: Operation(params=LodRender, call_bytes=RENDER_WORKING_BYTES),
    }

    def load(self, folder: Path, device: str) -> LodModel:
        return LodModel(load(folder), load_scene(folder), device)


INFERENCE = LodInference()
