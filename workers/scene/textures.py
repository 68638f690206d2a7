"""Material textures: loading images as linear RGB and evaluating any colour-or-texture at UVs.

UV convention (Mitsuba's): (0, 0) is the top-left corner of the image, u grows to the right,
v grows downwards; texel centres sit at half-integers; lookups repeat outside [0, 1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from workers.scene import spec
from workers.scene.errors import SceneError
from workers.scene.image_io import read_exr, srgb_to_linear


def load_image_texture(tex: spec.ImageTexture, field: str, base_dir: Path | None) -> np.ndarray:
    """(H, W, 3) float32 linear RGB: 8-bit images are sRGB-decoded, EXR is read as linear."""
    path = Path(tex.path)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    where = f"{field}.path"
    if not path.is_file():
        raise SceneError(where, f"texture file not found: {path}")
    try:
        if path.suffix.lower() == ".exr":
            image = read_exr(path)
        else:
            with Image.open(path) as opened:
                encoded = np.asarray(opened.convert("RGB"), dtype=np.float64) / 255.0
            image = srgb_to_linear(encoded)
    except (ValueError, OSError, UnidentifiedImageError) as error:
        raise SceneError(where, f"cannot read texture {path.name}: {error}") from error
    if not np.isfinite(image).all() or image.min() < 0:
        raise SceneError(where, f"texture {path.name} has NaN/Inf or negative texels")
    return np.ascontiguousarray(image, dtype=np.float32)


def evaluate_texture(
    texture: spec.Albedo | spec.ImageTexture | spec.CheckerTexture, image: np.ndarray | None, uv: np.ndarray
) -> np.ndarray:
    """(N, 3) float32 colours at (N, 2) `uv`: a constant, a procedural checker, or `image` bilinearly."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    uv = np.where(np.isfinite(uv), uv, 0.0)  # a NaN UV from a degenerate hit must not poison a colour
    match texture:
        case spec.CheckerTexture():
            cells = (np.floor(uv * texture.scale).sum(axis=1) % 2.0).astype(np.int64)
            colours = np.asarray([texture.color0, texture.color1], dtype=np.float32)
            return colours[cells]
        case spec.ImageTexture():
            if image is None:
                raise ValueError("an image texture needs its loaded image")
            return bilinear_repeat(image, uv)
        case _:
            return np.broadcast_to(np.asarray(texture, dtype=np.float32), (len(uv), 3)).copy()


def bilinear_repeat(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear interpolation between texel centres with repeat wrapping on both axes."""
    height, width = image.shape[:2]
    uv = uv % 1.0  # repeat, and keep huge coordinates away from int64 overflow
    x = uv[:, 0] * width - 0.5
    y = uv[:, 1] * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64) % width, y0.astype(np.int64) % height
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    top = image[y0, x0] * (1.0 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1.0 - fx) + image[y1, x1] * fx
    return (top * (1.0 - fy) + bottom * fy).astype(np.float32)
