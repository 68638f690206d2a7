"""Serving an `explore` artifact: the network renders its variable scene at any setting of the variables.

`render`: `params.values` sets the named variables, in their own units (a colour as RGB, an offset as
xyz, an angle in degrees, a switch by object name) or, with `normalised`, as their entries of v; the
variables not named sit at the middle of their ranges. Embree gives the G-buffers of the view, the network
the radiance per pixel, averaged over `antialiasing` sample points per pixel: by default RGSS's 4
(`evaluate.RGSS`), or an s x s grid of centres as the frames the report measures (4 x 4). A camera that is
itself a variable is set through its values; otherwise `params.camera` overrides the scene camera's
fields.

`query`: radiance for per-pixel G-buffers the caller computed (world position, shading normal, w_o,
albedo, roughness, emission, and optionally `hit`: rows whose ray escaped, whose radiance is their
`emission`, the environment's along the ray, as in a frame) and a scene vector per row, normalised: the
radiance leaving each surface towards w_o. A caller that follows mirrors into its buffers
(`mirror_bounces`) multiplies it by their colours.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from workers.models.explore.artifact import load
from workers.models.explore.evaluate import RGSS, network_image, pixel_offsets
from workers.models.explore.features import pixel_features
from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.render.gbuffer import GBuffers
from workers.render.variable_tracer import VariableTracer
from workers.runtime.view_render import MAX_SAMPLES, RENDER_WORKING_BYTES, CameraParams, scene_bytes
from workers.scene.format.variables import vector_from_values
from workers.scene.geometry.variable_scene import CompiledVariableScene

# Working memory, estimated from the network's shapes (not measured): a query's output (12 bytes a pixel)
# and its encoded copy; per pixel, its features and the network's hidden layers.
QUERY_ROW_BYTES, QUERY_ACTIVATION_ROW_BYTES = 32, 2 << 10


class ExploreRender(BaseModel):
    model_config = ConfigDict(extra="forbid")

    camera: CameraParams = Field(default_factory=CameraParams)
    values: dict[str, float | list[float] | str] = Field(
        default_factory=dict, description="variable name -> value (own units, or v entries with `normalised`)"
    )
    normalised: bool = Field(False, description="values are entries of v in [0, 1]")
    antialiasing: Literal["rgss"] | Annotated[int, Field(ge=1, le=8)] = Field(
        RGSS,
        description="rgss: 4 rotated-grid samples a pixel; or samples per pixel side on a grid (the "
        "report's frames: 4, 3.2x the time of rgss; 1 aliases)",
    )


class PixelQuery(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ExploreModel:
    def __init__(self, folder: Path, device: str) -> None:
        self.artifact = load(folder, device)
        self.scene = CompiledVariableScene(self.artifact.scene, self.artifact.scene_dir)
        self.tracer = VariableTracer(self.scene)
        weights = sum(p.numel() * p.element_size() for p in self.artifact.model.parameters())
        self.nbytes = weights + scene_bytes(self.scene.base)

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        if operation == RENDER:
            return self._render(params)
        return self._query(arrays)

    def _render(self, params: ExploreRender) -> Answer:
        spec = self.artifact.scene
        try:
            v = vector_from_values(spec, params.values, params.normalised)
        except ValueError as error:
            raise ValueError(f"params.{error}") from None
        cameras = [variable.name for variable in spec.variables if variable.type == "camera"]
        if cameras and (params.camera.position is not None or params.camera.target is not None):
            raise ValueError(
                f"params.camera: the camera is the variable {cameras[0]!r}; set it in params.values"
            )
        state = self.scene.at(v)
        camera = params.camera.over(state.compiled.spec.camera)
        per_pixel = len(pixel_offsets(params.antialiasing))
        samples = camera.width * camera.height * per_pixel
        if samples > MAX_SAMPLES:
            raise ValueError(
                f"params.antialiasing: {camera.width}x{camera.height} at {per_pixel} samples a "
                f"pixel is {samples} network samples, more than {MAX_SAMPLES}; lower it or the size"
            )
        with torch.inference_mode():
            image, seconds = network_image(
                self.artifact.model, self.tracer.state_tracer(state), camera, self.artifact.box, v,
                camera.width, camera.height, params.antialiasing, self.artifact.config.mirror_bounces,
            )  # fmt: skip
        return Answer(
            {"image": image}, {"v": v.tolist(), "dimensions": self.artifact.dimensions, "seconds": seconds}
        )

    def _query(self, arrays: dict[str, np.ndarray]) -> Answer:
        v = arrays["v"]
        k = len(self.artifact.dimensions)
        if v.shape[1] != k:
            raise ValueError(f"arrays.v: the scene has {k} dimension(s), got {v.shape[1]} per row")
        if not np.all(np.isfinite(v)) or v.min(initial=0) < 0 or v.max(initial=1) > 1:
            raise ValueError("arrays.v: every entry must be in [0, 1]")
        n = len(v)
        buffers = GBuffers(
            position=arrays["position"][None], normal=arrays["normal"][None], wo=arrays["wo"][None],
            albedo=arrays["albedo"][None], roughness=arrays["roughness"][None],
            emission=arrays["emission"][None], hit=arrays.get("hit", np.ones(n, bool)).reshape(1, n),
            throughput=np.ones((1, n, 3), np.float32),
        )  # fmt: skip
        features = pixel_features(buffers, self.artifact.box, np.zeros(0))[0]
        features = np.concatenate([features, v.astype(np.float32)], axis=-1)
        model = self.artifact.model
        device = next(model.parameters()).device
        with torch.inference_mode():
            radiance = model.radiance(
                torch.from_numpy(features).to(device), torch.from_numpy(arrays["emission"]).to(device)
            )
        return Answer({"radiance": radiance.float().cpu().numpy()}, {"dimensions": self.artifact.dimensions})


class ExploreInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        QUERY: Operation(
            params=PixelQuery,
            inputs={
                "position": ArraySpec("float32", (None, 3)),
                "normal": ArraySpec("float32", (None, 3)),
                "wo": ArraySpec("float32", (None, 3)),
                "albedo": ArraySpec("float32", (None, 3)),
                "roughness": ArraySpec("float32", (None, 1)),
                "emission": ArraySpec("float32", (None, 3)),
                "v": ArraySpec("float32", (None, None)),
                "hit": ArraySpec("bool", (None,), required=False),
            },
            batched=True,
            row_bytes=QUERY_ROW_BYTES,
            activation_row_bytes=QUERY_ACTIVATION_ROW_BYTES,
        ),
        RENDER: Operation(params=ExploreRender, call_bytes=RENDER_WORKING_BYTES),
    }

    def load(self, folder: Path, device: str) -> ExploreModel:
        return ExploreModel(Path(folder), device)


INFERENCE = ExploreInference()
