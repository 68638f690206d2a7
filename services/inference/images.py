"""Images out of `render`: linear float32 as OpenEXR (the default) or an sRGB PNG preview, chosen by the
request's `Accept` header."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from workers.scene.importers.image_io import write_exr, write_png

EXR, PNG = "image/x-exr", "image/png"
WRITERS = {EXR: (".exr", write_exr), PNG: (".png", write_png)}


def media_type_for(accept: str | None) -> str:
    """PNG when the caller asks for it (and not for EXR first); EXR otherwise."""
    wanted = [part.split(";")[0].strip() for part in (accept or "").split(",")]
    return next((m for m in wanted if m in WRITERS), EXR)


def encode(image: np.ndarray, media_type: str) -> bytes:
    suffix, write = WRITERS[media_type]
    with tempfile.TemporaryDirectory(prefix="nbake-image-") as folder:
        path = Path(folder) / f"image{suffix}"
        write(path, image[..., 0] if image.shape[-1] == 1 else image)
        return path.read_bytes()
