"""`:render` for kinds that path-trace a view of their artifact (`lod`, `lsnif`): the parameters every such
kind shares, the camera a request resolves to and the render itself.

The camera arrives as `params.camera` = {position, target, up, fov, width, height}. A field left out is
taken from the camera of the scene the artifact keeps, or from a camera framing the model when the view
has no scene camera. `background` is `scene` (the scene the artifact keeps; refused with the reason when
it kept none) or `neutral` (the model alone under a grey sky and a sun).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from workers.render.integrator import PathTracer
from workers.render.render import RenderResult, RenderSettings, render
from workers.runtime.threads import torch_threads
from workers.scene.format.spec import Camera, Vec3
from workers.scene.geometry.compile import CompiledScene
from workers.scene.portability.portable import StoredScene

SCENE, NEUTRAL = "scene", "neutral"
MAX_SIZE = 4096
MAX_SAMPLES = 1 << 24  # pixels x spp of one request: a 1024^2 frame at 16 spp, minutes on this CPU
# Working memory the inference service admits a path-traced view with (`Operation.call_bytes`): a 512^2
# view of an lsnif or lod artifact at 1 spp peaked at 49 and 53 MB over the process's RSS before it (the
# wavefront and the image's accumulators). Not scaled by the view's size: a larger view needs more.
RENDER_WORKING_BYTES = 64 << 20


class CameraParams(BaseModel):
    """A view; every field is optional and falls back to the view's own camera."""

    model_config = ConfigDict(extra="forbid")

    position: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 | None = None
    fov: float | None = Field(None, gt=0.1, lt=179.0, description="vertical, degrees")
    width: int | None = Field(None, ge=1, le=MAX_SIZE)
    height: int | None = Field(None, ge=1, le=MAX_SIZE)

    def over(self, base: Camera) -> Camera:
        """`base` with the fields given here; ValueError naming `params.camera` for an ill-posed view."""
        try:
            return Camera.model_validate(base.model_dump() | self.model_dump(exclude_none=True))
        except ValidationError as error:
            raise ValueError(f"params.camera: {error.errors()[0]['msg']}") from None


class ViewRender(BaseModel):
    """The parameters of a path-traced view; kinds add their own (a LoD, say) by subclassing."""

    model_config = ConfigDict(extra="forbid")

    camera: CameraParams = Field(default_factory=CameraParams)
    spp: int = Field(4, ge=1, le=4096, description="samples per pixel")
    max_depth: int = Field(8, ge=1, le=64, description="path segments, as in `nbake render`")
    seed: int = Field(0, ge=0)
    background: Literal["scene", "neutral"] = Field(
        SCENE, description="`scene`: the scene the artifact keeps; `neutral`: the model alone, grey sky"
    )

    def settings(self, camera: Camera) -> RenderSettings:
        samples = camera.width * camera.height * self.spp
        if samples > MAX_SAMPLES:
            raise ValueError(
                f"params.spp: {camera.width}x{camera.height} at {self.spp} spp is {samples:,} samples; "
                f"at most {MAX_SAMPLES:,} per request"
            )
        return RenderSettings(
            spp=self.spp, width=camera.width, height=camera.height, max_depth=self.max_depth, seed=self.seed
        )


def refuse_missing_scene(stored: StoredScene) -> None:
    """ValueError naming `params.background` when the artifact kept no scene to render in."""
    if stored.spec is None:
        raise ValueError(
            f"params.background: this artifact keeps no scene: {stored.reason}; "
            "ask for background: neutral to see the model alone"
        )


def scene_bytes(scene: CompiledScene) -> int:
    """What a compiled scene holds in memory: its per-triangle arrays and its environment image."""
    arrays = [value for value in vars(scene).values() if isinstance(value, np.ndarray)]
    return sum(a.nbytes for a in arrays)


def render_view(tracer: PathTracer, params: ViewRender, camera: Camera) -> RenderResult:
    """The frame, with networks in inference mode and one torch thread per render thread (see
    `torch_threads`)."""
    with torch.inference_mode(), torch_threads(1):
        return render(tracer, params.settings(camera), view=camera)
