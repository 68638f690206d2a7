"""Material textures: loading images as linear RGB and evaluating any colour-or-texture at UVs.

UV convention (Mitsuba's, and glTF's): (0, 0) is the top-left corner of the image, u grows to the right,
v grows downwards; texel centres sit at half-integers. Outside [0, 1) lookups wrap per axis as glTF's
samplers do: `repeat`, `clamp` (to the edge texels) or `mirror` (mirrored repeat).

Colour spaces: an image texture's `color_space` says how its texels are decoded; by default 8-bit images
are sRGB (decoded to linear with the sRGB EOTF) and EXR is linear. Data textures (metallic-roughness,
normals, transmission) are declared `linear` by the importers, as glTF and UsdPreviewSurface require.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image, UnidentifiedImageError

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.importers.gltf import embedded_image
from workers.scene.importers.image_io import read_exr, srgb_to_linear
from workers.scene.importers.usd import package_member

# An image's pixels (a texture, an environment map): 8192 x 8192 decodes to 1.6 GB of float64 texels, the
# most a sampler actor affords; a larger one is refused from its header, at upload and again before decoding.
MAX_TEXTURE_PIXELS = 8192 * 8192
_OVER = f"over the limit of {MAX_TEXTURE_PIXELS:,} pixels (MAX_TEXTURE_PIXELS)"


def load_image_texture(tex: spec.ImageTexture, field: str, base_dir: Path | None) -> np.ndarray:
    """(H, W, 3) float32 RGB, decoded as `tex.color_space` says (module docstring); an `image` index reads
    that image out of the glTF file at `path`."""
    path, where = _resolved(tex, base_dir), f"{field}.path"
    if not path.is_file():
        raise SceneError(where, f"texture file not found: {path}")
    try:
        if tex.image is None and path.suffix.lower() == ".exr":
            check_exr_size(path, where)
            image = read_exr(path)
            if tex.color_space == "srgb":
                image = srgb_to_linear(image)
        else:
            with _opened(_encoded(tex, path), where, path.name) as opened:
                encoded = np.asarray(opened.convert("RGB"), dtype=np.float64) / 255.0
            image = encoded if tex.color_space == "linear" else srgb_to_linear(encoded)
    except SceneError:
        raise
    except (ValueError, OSError, UnidentifiedImageError) as error:
        raise SceneError(where, f"cannot read texture {path.name}: {error}") from error
    if not np.isfinite(image).all() or image.min() < 0:
        raise SceneError(where, f"texture {path.name} has NaN/Inf or negative texels")
    return np.ascontiguousarray(image, dtype=np.float32)


def image_textures(scene: spec.SceneSpec) -> Iterator[tuple[str, spec.ImageTexture]]:
    """(field, texture) for every image texture of the scene's materials (an aggregate's base included)."""
    for name, material in scene.materials.items():
        if isinstance(material, spec.AggregateMaterial):
            material, name = material.base, f"{name}.base"
        for field, value in material:
            if isinstance(value, spec.ImageTexture):
                yield f"materials.{name}.{field}", value


def check_texture_size(tex: spec.ImageTexture, field: str, base_dir: Path | None) -> None:
    """SceneError unless the texture's header declares at most MAX_TEXTURE_PIXELS; only the header is read
    (an 83-byte PNG may declare 100000 x 100000)."""
    path = _resolved(tex, base_dir)
    try:
        if tex.image is None and path.suffix.lower() == ".exr":
            check_exr_size(path, f"{field}.path")
        else:
            with _opened(_encoded(tex, path), f"{field}.path", path.name):
                pass
    except SceneError:
        raise
    except (ValueError, OSError, UnidentifiedImageError) as error:
        raise SceneError(f"{field}.path", f"cannot read texture {path.name}: {error}") from error


def check_exr_size(path: Path, where: str) -> None:
    """SceneError if an EXR's header declares more than MAX_TEXTURE_PIXELS (its reader allocates them all)."""
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            low, high = exr.header()["dataWindow"]
    except Exception as error:  # OpenEXR raises bare RuntimeError/ValueError subclasses on corrupt files
        raise SceneError(where, f"cannot read {path.name} as OpenEXR: {error}") from None
    width, height = (int(side) + 1 for side in high - low)
    _check_pixels(width, height, where, path.name)


def _check_pixels(width: int, height: int, where: str, name: str) -> None:
    if width * height > MAX_TEXTURE_PIXELS:
        raise SceneError(where, f"image {name} is {width} x {height} pixels, {_OVER}")


def _resolved(tex: spec.ImageTexture, base_dir: Path | None) -> Path:
    path = Path(tex.path)
    return base_dir / path if not path.is_absolute() and base_dir is not None else path


def _encoded(tex: spec.ImageTexture, path: Path) -> Path | io.BytesIO:
    """The encoded image: the file, or an image embedded in a glTF file or packed in a USDZ package."""
    if tex.member is not None:
        return io.BytesIO(package_member(path, tex.member))
    return path if tex.image is None else io.BytesIO(embedded_image(path, tex.image))


@contextmanager
def _opened(source: Path | io.BytesIO, where: str, name: str) -> Iterator[Image.Image]:
    """The image with its header read and its size checked against MAX_TEXTURE_PIXELS, not yet decoded."""
    try:
        opened = Image.open(source)
    except Image.DecompressionBombError:
        raise SceneError(where, f"image {name} is {_OVER}") from None
    with opened:
        _check_pixels(*opened.size, where, name)
        yield opened


class MipChain:
    """An image and its box-filtered halvings down to 1 x 1, for lookups over a footprint (trilinear
    filtering between the two levels whose texels are closest to the footprint's width, Williams 1983)."""

    def __init__(self, image: np.ndarray):
        self.levels = [np.asarray(image, dtype=np.float32)]
        while max(self.levels[-1].shape[:2]) > 1:
            level = self.levels[-1]
            h, w = level.shape[:2]
            level = np.pad(level, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")  # odd sizes: repeat the edge
            halved = 0.25 * (level[0::2, 0::2] + level[1::2, 0::2] + level[0::2, 1::2] + level[1::2, 1::2])
            self.levels.append(halved)
        self.log2_texels = 0.5 * np.log2(self.levels[0].shape[0] * self.levels[0].shape[1])

    def lookup(self, uv: np.ndarray, wrap_u: str, wrap_v: str, footprint: np.ndarray | None) -> np.ndarray:
        """Bilinear at level 0, or trilinear where `footprint` (log2 of the footprint's width in UV units;
        -inf where unknown) covers more than a texel."""
        if footprint is None:
            return bilinear(self.levels[0], uv, wrap_u, wrap_v)
        lod = np.clip(
            np.nan_to_num(footprint + self.log2_texels, nan=0.0, neginf=0.0), 0, len(self.levels) - 1
        )
        out = np.empty((len(uv), 3), np.float32)
        below = np.floor(lod).astype(np.int64)
        for level in np.unique(below):
            rows = np.flatnonzero(below == level)
            fine = bilinear(self.levels[level], uv[rows], wrap_u, wrap_v)
            coarse = bilinear(self.levels[min(level + 1, len(self.levels) - 1)], uv[rows], wrap_u, wrap_v)
            t = (lod[rows] - level)[:, None]
            out[rows] = fine * (1.0 - t) + coarse * t
        return out


def evaluate_texture(
    texture: spec.Albedo | spec.ImageTexture | spec.CheckerTexture,
    image: np.ndarray | MipChain | None,
    uv: np.ndarray,
    footprint: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 3) float32 colours at (N, 2) `uv`: a constant, a procedural checker, or `image` bilinearly (a
    `MipChain` over `footprint`, `MipChain.lookup`)."""
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
            if isinstance(image, MipChain):
                return image.lookup(uv, texture.wrap_u, texture.wrap_v, footprint)
            return bilinear(image, uv, texture.wrap_u, texture.wrap_v)
        case _:
            return np.broadcast_to(np.asarray(texture, dtype=np.float32), (len(uv), 3)).copy()


def _texel_indices(coordinate: np.ndarray, size: int, wrap: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two texels a bilinear lookup at `coordinate` (a UV along one axis) blends; the second's weight."""
    if wrap == "repeat":
        coordinate = coordinate % 1.0  # and keep huge coordinates away from int64 overflow
    elif wrap == "mirror":
        coordinate = coordinate % 2.0
        coordinate = np.where(coordinate > 1.0, 2.0 - coordinate, coordinate)
    else:
        coordinate = np.clip(coordinate, 0.0, 1.0)
    x = coordinate * size - 0.5
    x0 = np.floor(x)
    fraction = x - x0
    first = x0.astype(np.int64)
    second = first + 1
    if wrap == "repeat":
        return first % size, second % size, fraction
    # clamp and mirror: the texels beyond an edge are the edge texel itself (mirroring repeats it too)
    return np.clip(first, 0, size - 1), np.clip(second, 0, size - 1), fraction


def bilinear(image: np.ndarray, uv: np.ndarray, wrap_u: str = "repeat", wrap_v: str = "repeat") -> np.ndarray:
    """Bilinear interpolation between texel centres, wrapping each axis as glTF's sampler modes do."""
    height, width = image.shape[:2]
    x0, x1, fx = _texel_indices(uv[:, 0], width, wrap_u)
    y0, y1, fy = _texel_indices(uv[:, 1], height, wrap_v)
    fx, fy = fx[:, None], fy[:, None]
    top = image[y0, x0] * (1.0 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1.0 - fx) + image[y1, x1] * fx
    return (top * (1.0 - fy) + bottom * fy).astype(np.float32)
