"""What the inference service answers: a query's NumPy arrays with their metadata, and a rendered image
(the encoded file, its frame time, and its pixels as a NumPy array).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuralbake_client.errors import NeuralbakeError
from neuralbake_client.exr import read_exr

EXR, PNG = "image/x-exr", "image/png"
MEDIA_TYPES = {".exr": EXR, ".png": PNG}
FRAME_TIMING = "frame"  # the Server-Timing metric that carries a render's frame time


@dataclass(frozen=True)
class QueryAnswer:
    """The output arrays (`answer["hit"]`) and `meta`, e.g. the names that indices refer to."""

    artifact_id: str
    kind: str
    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]


@dataclass(frozen=True)
class RenderedImage:
    """An image of an artifact: `data` is the file (OpenEXR, linear float32, or an sRGB PNG)."""

    artifact_id: str
    media_type: str
    data: bytes
    frame_time_s: float | None = None  # the server's time for the frame, when it says

    def save(self, path: str | os.PathLike) -> Path:
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(self.data)
        return target

    def pixels(self) -> np.ndarray:
        """The linear image, (H, W, 3) RGB or (H, W, 1), float32 (EXR only; open a PNG with any image
        library)."""
        if self.media_type != EXR:
            raise NeuralbakeError(f"pixels() decodes {EXR}; this image is {self.media_type}")
        channels = read_exr(self.data)
        names = ["R", "G", "B"] if {"R", "G", "B"} <= channels.keys() else sorted(channels)[:1]
        return np.stack([channels[name].astype(np.float32) for name in names], axis=-1)


def media_type_for(path: str | os.PathLike) -> str:
    """The image format an output file's suffix asks for."""
    suffix = Path(path).suffix.lower()
    if suffix not in MEDIA_TYPES:
        raise ValueError(f"{path}: an image ends in .exr (linear float32) or .png (sRGB)")
    return MEDIA_TYPES[suffix]


def frame_time(server_timing: str | None) -> float | None:
    """Seconds from a `Server-Timing: frame;dur=<ms>` header (W3C Server Timing), if present."""
    for metric in (server_timing or "").split(","):
        name, *params = (part.strip() for part in metric.split(";"))
        if name == FRAME_TIMING:
            for param in params:
                key, _, value = param.partition("=")
                if key == "dur":
                    try:
                        return float(value) / 1000
                    except ValueError:
                        return None
    return None
