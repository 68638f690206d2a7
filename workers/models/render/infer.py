"""Serving a `render` artifact: its stored images (the radiance and each G-buffer) as layers.

`query` returns whole layers, or with `pixels` (N, 2) as (x, y) only those pixels' values; `render`
returns one layer as the image. Nothing is traced: the artifact is the reference image a job made.

`render` accepts `params.camera`, so that one call renders an artifact of any kind, but it has only the
view its job rendered. The artifact does not record that view, so a camera's position, target, up and
fov are not checked. A width or height other than the stored image's is refused.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.runtime.view_render import CameraParams
from workers.scene.importers.image_io import read_exr_channels

MAIN_LAYER = "image"
# Working memory: a pixel's values in every layer (up to 16 float32 channels) and their encoded copy; the
# stored view's encoded copy, admitted as a 512x512 RGBA float32 image. Larger stored images, and a query
# without `pixels` (every layer, whole), take more than that: not counted (reserving a large image's
# bytes for each of them cut served requests by half in the inference load bench).
PIXEL_BYTES, STORED_VIEW_BYTES = 128, 4 << 20


class LayerQuery(BaseModel):
    model_config = ConfigDict(extra="forbid")

    layers: list[str] | None = Field(None, description="layer names (default: every stored layer)")


class LayerRender(BaseModel):
    model_config = ConfigDict(extra="forbid")

    layer: str = Field(MAIN_LAYER, description="`image` (radiance) or a G-buffer such as `albedo`")
    camera: CameraParams = Field(
        default_factory=CameraParams, description="the stored view only: a size, if given, must be its own"
    )


def _read_layer(path: Path) -> np.ndarray:
    """The single image in one of the artifact's EXRs, (H, W, C): RGB, or one channel `Y`."""
    (image,) = read_exr_channels(path).values()
    return image if image.ndim == 3 else image[..., None]


class RenderModel:
    def __init__(self, layers: dict[str, np.ndarray]) -> None:
        self.layers = layers
        self.nbytes = sum(layer.nbytes for layer in layers.values())

    def _layer(self, name: str, field: str) -> np.ndarray:
        if name not in self.layers:
            raise ValueError(
                f"{field}: no layer {name!r}; this artifact has {', '.join(sorted(self.layers))}"
            )
        return self.layers[name]

    def _stored_view(self, params: LayerRender) -> np.ndarray:
        image = self._layer(params.layer, "layer")
        height, width = image.shape[:2]
        for field, asked, stored in (
            ("width", params.camera.width, width),
            ("height", params.camera.height, height),
        ):
            if asked is not None and asked != stored:
                raise ValueError(
                    f"params.camera.{field}: this artifact holds one {width}x{height} view; it cannot be "
                    f"rendered at {field} {asked}"
                )
        return image

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        if operation == RENDER:
            return Answer(arrays={"image": self._stored_view(params)})
        names = params.layers or sorted(self.layers)
        chosen = {name: self._layer(name, "layers") for name in names}
        pixels = arrays.get("pixels")
        if pixels is None:
            return Answer(arrays=chosen)
        height, width = self.layers[MAIN_LAYER].shape[:2]
        x, y = pixels[:, 0], pixels[:, 1]
        if np.any((x < 0) | (x >= width) | (y < 0) | (y >= height)):
            raise ValueError(f"pixels: (x, y) must lie inside the {width}x{height} image")
        return Answer(arrays={name: layer[y, x] for name, layer in chosen.items()})


class RenderInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        QUERY: Operation(
            params=LayerQuery,
            inputs={"pixels": ArraySpec("int64", (None, 2), required=False)},
            row_bytes=PIXEL_BYTES,
        ),
        RENDER: Operation(params=LayerRender, call_bytes=STORED_VIEW_BYTES),
    }

    def load(self, folder: Path, device: str) -> RenderModel:
        files = sorted(folder.glob(f"{MAIN_LAYER}*.exr"))
        layers = {
            path.name.removesuffix(".exr").removeprefix(f"{MAIN_LAYER}.") or MAIN_LAYER: _read_layer(path)
            for path in files
        }
        return RenderModel(layers)


INFERENCE = RenderInference()
