"""Serving a `prt` artifact: relighting under any environment map from any viewpoint.

`render`: a camera (`params.camera`, fields defaulting to the scene camera) and a lighting
(`params.lighting`: a built-in HDRI, a procedural `sky` or `studio` map, or, with `path` set to any name, the
lat-long map uploaded as the `environment` array; with `rotate` and `scale`) in, the frame out: G-buffer,
the K (`params.wavelets`) wavelets of the lighting, the network's indirect light and path-traced direct
light at `params.spp` under the map itself (full resolution, importance-sampled), denoised if
`params.denoise`; `params.checkerboard` runs the network at half the pixels. Each defaults to the
artifact's frame (`evaluation_spp`, the count its job chose by counted cost unless its config fixed one;
`denoise_direct`; `checkerboard`): the frame its report times against path tracing. The service adds
the frame time as `Server-Timing`.

`query`: indirect radiance at given G-buffer points (world position, normal, direction towards the
viewer, kd, ks, roughness) under a lighting, the same as `render`'s (an uploaded map too): what a
rasteriser needs to add the network's light itself.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.models.prt.artifact import PrtArtifact, load
from workers.models.prt.frame import render_frame
from workers.models.prt.gbuffer import SurfaceInputs
from workers.models.prt.lighting import cube_of, latlong_of
from workers.models.prt.network import MAX_PAIRS_PER_CHUNK, PrtNetwork
from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.render.embree import RayScene
from workers.render.integrator import PathTracer
from workers.runtime.threads import torch_threads
from workers.runtime.view_render import (
    RENDER_WORKING_BYTES,
    SCENE,
    ViewRender,
    refuse_missing_scene,
    scene_bytes,
)
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import EnvironmentMap

DEFAULT_LIGHTING = EnvironmentMap(builtin="courtyard")
UPLOAD = "environment"
ENVIRONMENT = ArraySpec("float32", (None, None, 3), required=False, per_call=True)  # a lat-long map
MAX_UPLOAD_TEXELS = 4096 * 2048
SERVED_WIDTH = 1024  # procedural maps are generated this wide; larger maps are box-filtered down to it
# Working memory, estimated from the network's shapes (not measured): a query's output (12 bytes a point)
# and its encoded copy; per point, its hash-grid and SH features; per call, one chunk of pixel-wavelet
# pairs through f (input features and two hidden layers, about 512 bytes a pair).
QUERY_ROW_BYTES, QUERY_ACTIVATION_ROW_BYTES = 32, 4 << 10
TRANSPORT_BYTES = MAX_PAIRS_PER_CHUNK * 512


class Relighting(BaseModel):
    model_config = ConfigDict(extra="forbid")

    lighting: EnvironmentMap | None = Field(
        None, description="the environment map; default: the scene's own (or the courtyard HDRI)"
    )
    wavelets: int | None = Field(None, ge=1, description="K: wavelets per frame; default: the artifact's")


class PrtQuery(Relighting):
    pass


class PrtRender(ViewRender, Relighting):
    """`spp` is the direct light's samples per pixel, before `denoise` filters it; `max_depth` is not used
    (direct light is two path segments, the network gives the rest); `background` can only be `scene`
    (relighting needs it)."""

    spp: int | None = Field(
        None,
        ge=1,
        le=4096,
        description="the direct light's paths per pixel; default: the artifact's evaluation_spp",
    )
    background: Literal["scene"] = SCENE
    denoise: bool | None = Field(
        None,
        description="filter the direct light guided by the G-buffer; default: the artifact's denoise_direct",
    )
    checkerboard: bool | None = Field(
        None,
        description="the network shades half the pixels, the rest filled from same-surface neighbours; "
        "default: the artifact's checkerboard",
    )


class PrtModel:
    def __init__(self, artifact: PrtArtifact) -> None:
        self.artifact = artifact
        self.config = artifact.config
        self.model: PrtNetwork = artifact.model
        self.stored = artifact.scene
        self.scene = self.stored.compiled() if self.stored.spec is not None else None
        self.rays = RayScene(self.scene.positions) if self.scene is not None else None
        parameters = sum(t.numel() * t.element_size() for t in self.model.state_dict().values())
        self.nbytes = parameters + (scene_bytes(self.scene) if self.scene is not None else 0)

    def _lighting(self, params: Relighting, upload: np.ndarray | None):
        env = params.lighting
        if env is None:
            own = self.stored.spec.environment if self.stored.spec is not None else None
            env = own if isinstance(own, EnvironmentMap) and own.path is None else DEFAULT_LIGHTING
        if upload is not None and env.path is None:
            raise ValueError("arrays.environment: an uploaded map needs params.lighting.path (any name)")
        if upload is not None and upload.shape[0] * upload.shape[1] > MAX_UPLOAD_TEXELS:
            raise ValueError(f"arrays.environment: at most {MAX_UPLOAD_TEXELS} texels")
        try:
            # Full resolution (up to SERVED_WIDTH) for the direct light, the artifact's cube for the network.
            latlong, rotation = latlong_of(env, SERVED_WIDTH, "params.lighting", upload)
        except SceneError as error:
            raise ValueError(str(error)) from None
        return latlong, rotation, cube_of(latlong, rotation, self.config.cube_size)

    def _k(self, params: Relighting) -> int:
        total = self.config.n_wavelets
        if params.wavelets is not None and params.wavelets > total:
            raise ValueError(
                f"params.wavelets: at most {total} (the artifact's 6 x {self.config.cube_size}^2 cube)"
            )
        return params.wavelets or self.config.wavelets

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        if operation == RENDER:
            return self._render(params, arrays.get(UPLOAD))
        return self._query(params, arrays)

    def _render(self, params: PrtRender, upload: np.ndarray | None) -> Answer:
        refuse_missing_scene(self.stored)
        k = self._k(params)
        camera = params.camera.over(self.stored.spec.camera)
        params = params.model_copy(update={"spp": params.spp or self.config.evaluation_spp})
        params.settings(camera)  # refuses requests over the sample budget, naming params.spp
        latlong, rotation, cube = self._lighting(params, upload)
        lit = replace(self.scene, environment_image=latlong.astype(np.float32), environment_rotation=rotation)
        start = time.perf_counter()
        tracer = PathTracer(lit, intersector=self.rays)
        with torch_threads(1):
            frame = render_frame(
                self.model, self.artifact.box, self.artifact.objects, tracer, cube, camera,
                k=k, weighting=self.config.selection, spp=params.spp, seed=params.seed, threads=2,
                denoise=self.config.denoise_direct if params.denoise is None else params.denoise,
                checkerboard=self.config.checkerboard if params.checkerboard is None else params.checkerboard,
            )  # fmt: skip
        meta = {
            "wavelets": k,
            "frame_seconds": time.perf_counter() - start,
            "network_seconds": frame.network_seconds,
        }
        return Answer({"image": frame.image}, meta)

    def _query(self, params: PrtQuery, arrays: dict[str, np.ndarray]) -> Answer:
        from workers.models.prt.frame import predict_indirect

        _, _, cube = self._lighting(params, arrays.get(UPLOAD))
        normal = _unit(arrays["normal"], "normal")
        towards_viewer = _unit(arrays["view"], "view")
        facing = np.sum(normal * towards_viewer, axis=1, keepdims=True)
        normal = np.where(facing < 0, -normal, normal)
        reflected = 2 * np.abs(facing) * normal - towards_viewer
        n = len(normal)
        inputs = SurfaceInputs(
            hit=np.ones(n, bool),
            position=arrays["position"],
            normal=normal,
            reflected=reflected,
            kd=arrays["kd"],
            ks=arrays["ks"],
            roughness=arrays["roughness"],
            object_id=np.full(n, -1) if "object" not in arrays else arrays["object"].astype(np.int64),
        )
        objects = self.artifact.objects if "object" in arrays else np.array([-1])
        with torch_threads(1):
            indirect, _ = predict_indirect(
                self.model, inputs, self.artifact.box, objects, cube, self._k(params), self.config.selection
            )
        return Answer({"indirect": indirect}, {"wavelets": self._k(params)})


def _unit(v: np.ndarray, name: str) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    if (length < 1e-9).any():
        raise ValueError(f"arrays.{name}: row {int(np.flatnonzero(length < 1e-9)[0])} has zero length")
    return v / length


class PrtInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        RENDER: Operation(
            params=PrtRender,
            inputs={UPLOAD: ENVIRONMENT},
            call_bytes=RENDER_WORKING_BYTES + TRANSPORT_BYTES,
        ),
        QUERY: Operation(
            params=PrtQuery,
            inputs={
                "position": ArraySpec("float64", (None, 3)),
                "normal": ArraySpec("float64", (None, 3)),
                "view": ArraySpec("float64", (None, 3)),
                "kd": ArraySpec("float64", (None, 3)),
                "ks": ArraySpec("float64", (None, 3)),
                "roughness": ArraySpec("float64", (None,)),
                "object": ArraySpec("int64", (None,), required=False),
                UPLOAD: ENVIRONMENT,
            },
            batched=True,
            row_bytes=QUERY_ROW_BYTES,
            activation_row_bytes=QUERY_ACTIVATION_ROW_BYTES,
            call_bytes=TRANSPORT_BYTES,
        ),
    }

    def load(self, folder: Path, device: str) -> PrtModel:
        return PrtModel(load(folder, device))


INFERENCE = PrtInference()
