"""Reading and writing images: OpenEXR float32 for HDR data, 8-bit sRGB PNG for previews.

EXR layout: the main image is the `R`, `G`, `B` channels (or a single `Y` for grey);
extra named layers (G-buffers) are `<name>.R/.G/.B` or a single channel `<name>`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image


def _as_float32_image(array: np.ndarray, what: str) -> np.ndarray:
    """(H, W) or (H, W, 1|3) -> float32 (H, W) or (H, W, 3), C-contiguous as OpenEXR needs."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or 0 in a.shape:
        raise ValueError(f"{what}: expected an (H, W), (H, W, 1) or (H, W, 3) array, got shape {a.shape}")
    return np.ascontiguousarray(a)


def write_exr(path: str | Path, image: np.ndarray, channels: dict[str, np.ndarray] | None = None) -> None:
    """Write `image` (RGB, or grey as `Y`) and optional extra named layers as float32, ZIP-compressed."""
    main = _as_float32_image(image, "image")
    data = {"RGB" if main.ndim == 3 else "Y": main}
    for name, layer in (channels or {}).items():
        if name in ("RGB", "Y", "R", "G", "B") or not name:
            raise ValueError(f"layer name {name!r} is reserved for the main image")
        layer = _as_float32_image(layer, f"layer {name!r}")
        if layer.shape[:2] != main.shape[:2]:
            raise ValueError(f"layer {name!r} is {layer.shape[:2]}, the image is {main.shape[:2]}")
        data[name] = layer
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, data).write(str(path))


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """Every layer of an EXR as float32: `RGB`/`RGBA`/`Y` for the main image, layer names for the rest."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such EXR file: {path}")
    try:
        with OpenEXR.File(str(path)) as exr:
            return {name: np.asarray(c.pixels, dtype=np.float32) for name, c in exr.channels().items()}
    except Exception as error:  # OpenEXR raises bare RuntimeError/ValueError subclasses on corrupt files
        raise ValueError(f"cannot read {path.name} as OpenEXR: {error}") from error


def read_exr(path: str | Path) -> np.ndarray:
    """The main image of an EXR as (H, W, 3) float32: RGB (alpha dropped) or grey `Y` repeated."""
    layers = read_exr_channels(path)
    for name in ("RGB", "RGBA"):
        if name in layers:
            return np.ascontiguousarray(layers[name][..., :3])
    if "Y" in layers:
        return np.repeat(layers["Y"][..., None], 3, axis=2)
    raise ValueError(f"{Path(path).name} has no RGB or Y channels (found: {', '.join(sorted(layers))})")


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB OETF (IEC 61966-2-1) on values already clamped to [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """The sRGB EOTF: inverse of `linear_to_srgb`, for decoding 8-bit textures."""
    x = np.clip(encoded, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def tonemap(linear_rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB: scale by 2^exposure, map NaN to 0, clamp to [0, 1], sRGB OETF, round."""
    scaled = np.nan_to_num(np.asarray(linear_rgb, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    encoded = linear_to_srgb(scaled * 2.0**exposure)
    return np.round(encoded * 255.0).astype(np.uint8)


def write_png(path: str | Path, linear_rgb: np.ndarray, exposure: float = 0.0) -> None:
    """A preview PNG of a linear image ((H, W), (H, W, 1) or (H, W, 3)) through `tonemap`."""
    image = _as_float32_image(linear_rgb, "image")
    Image.fromarray(tonemap(image, exposure)).save(str(path))
