"""Lat-long environment maps: the direction <-> texel convention, loading, checking and procedural skies.

Convention (Mitsuba 3's `envmap`): a unit direction d maps to u = atan2(d.x, -d.z) / 2pi
wrapped to [0, 1) and v = acos(d.y) / pi; texel (row, column) covers u in
[column / W, (column + 1) / W) and v in [row / H, (row + 1) / H), so row 0 is +y (up)
and u = 0 looks along -z.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators.procedural import parse_params
from workers.scene.importers.image_io import read_exr
from workers.scene.importers.textures import check_exr_size

HDRI_DIR = Path(__file__).resolve().parents[3] / "assets" / "hdri"
NEGATIVE_RINGING = 0.05  # negatives within 5% of the mean are lossy-compression ringing, clamped to 0

Size = Annotated[int, Field(ge=2, le=16384)]
NonNegative = Annotated[FiniteFloat, Field(ge=0)]
RGB = tuple[NonNegative, NonNegative, NonNegative]


# --------------------------------------------------------------------------- convention


def direction_to_uv(directions: np.ndarray) -> np.ndarray:
    """(..., 3) directions (any length > 0) -> (..., 2) lat-long coordinates in [0, 1)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi) % 1.0
    u = np.where(u >= 1.0, 0.0, u)  # -tiny % 1.0 rounds to 1.0
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=-1)


def uv_to_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) for lat-long coordinates; the inverse of `direction_to_uv`."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    phi, theta = 2.0 * np.pi * u, np.pi * v
    sin_theta = np.sin(theta)
    return np.stack([sin_theta * np.sin(phi), np.cos(theta), -sin_theta * np.cos(phi)], axis=-1)


def texel_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) unit directions through texel centres."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    return uv_to_direction(u[None, :], v[:, None])


def texel_solid_angles(height: int, width: int) -> np.ndarray:
    """(H,) exact solid angle of one texel in each row; rows x W sum to 4pi."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (edges[:-1] - edges[1:]) * (2.0 * np.pi / width)


# --------------------------------------------------------------------------- procedural maps


class Params(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    width: Size = 512
    height: Size = 256


class SkyParams(Params):
    """A clear-sky gradient over a dim ground, plus a small sun disc carrying `sun_irradiance`."""

    sun_elevation: Annotated[FiniteFloat, Field(ge=-90, le=90)] = 35.0
    sun_azimuth: FiniteFloat = Field(default=45.0, description="degrees from -z towards +x")
    sun_radius: Annotated[FiniteFloat, Field(gt=0, le=20)] = Field(default=0.8, description="degrees")
    sun_irradiance: NonNegative = Field(default=40.0, description="irradiance on a plane facing the sun")
    sun_color: RGB = (1.0, 0.92, 0.8)
    zenith: RGB = (0.18, 0.35, 0.85)
    horizon: RGB = (0.8, 0.88, 1.0)
    ground: RGB = (0.12, 0.11, 0.1)


def sun_direction(elevation: float, azimuth: float) -> np.ndarray:
    """The unit direction towards a sun at `elevation` above the horizon and `azimuth` (degrees)."""
    return uv_to_direction(np.float64(azimuth / 360.0), np.float64((90.0 - elevation) / 180.0))


def sky(p: SkyParams) -> np.ndarray:
    d = texel_directions(p.height, p.width)
    up = np.clip(d[..., 1:2], 0.0, 1.0)
    zenith, horizon, ground = (np.asarray(c) for c in (p.zenith, p.horizon, p.ground))
    image = np.where(d[..., 1:2] >= 0, horizon + (zenith - horizon) * np.sqrt(up), ground)
    to_sun = sun_direction(p.sun_elevation, p.sun_azimuth)
    cos_angle = d @ to_sun
    glow = 0.3 * np.exp((cos_angle - 1.0) / 0.02)[..., None] * np.asarray(p.sun_color)
    image = image + np.where(d[..., 1:2] >= 0, glow, 0.0)
    disc = cos_angle >= np.cos(np.radians(p.sun_radius))
    if not disc.any():  # a disc smaller than a texel still lands in the nearest one
        disc = cos_angle == cos_angle.max()
    solid_angle = (disc * texel_solid_angles(p.height, p.width)[:, None]).sum()
    sun = p.sun_irradiance / solid_angle * np.asarray(p.sun_color)
    return np.where(disc[..., None], image + sun, image)


class StudioParams(Params):
    """A dim backdrop with `lights` rectangular softboxes of seeded colour, size and place."""

    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    lights: Annotated[int, Field(ge=0, le=64)] = 5
    background: NonNegative = 0.03
    intensity: NonNegative = Field(default=12.0, description="mean softbox radiance")


def studio(p: StudioParams) -> np.ndarray:
    rng = np.random.default_rng(p.seed)
    v_centres = (np.arange(p.height) + 0.5) / p.height
    u_centres = (np.arange(p.width) + 0.5) / p.width
    image = np.empty((p.height, p.width, 3))
    image[:] = (p.background * (1.5 - v_centres))[:, None, None]  # a little brighter above
    for _ in range(p.lights):
        u0, v0 = rng.uniform(0.0, 1.0), rng.uniform(0.12, 0.55)
        half_u = max(rng.uniform(0.015, 0.07), 0.5 / p.width)
        half_v = max(rng.uniform(0.02, 0.08), 0.5 / p.height)
        hue, saturation = rng.uniform(0.0, 1.0), rng.uniform(0.0, 0.6)
        colour = (1.0 - saturation) + saturation * _hue_rgb(hue)
        radiance = p.intensity * rng.uniform(0.5, 1.5) * colour
        rows = np.abs(v_centres - v0) <= half_v
        columns = np.abs((u_centres - u0 + 0.5) % 1.0 - 0.5) <= half_u  # wraps around u = 0
        image[np.ix_(rows, columns)] = radiance
    return image


def _hue_rgb(hue: float) -> np.ndarray:
    """A fully saturated colour of `hue` in [0, 1) (the HSV hexcone with S = V = 1)."""
    return np.clip(np.abs((hue * 6.0 + np.array([0.0, 4.0, 2.0])) % 6.0 - 3.0) - 1.0, 0.0, 1.0)


PROCEDURAL_MAPS = {"sky": (SkyParams, sky), "studio": (StudioParams, studio)}


# --------------------------------------------------------------------------- loading


def builtin_environment_names() -> list[str]:
    return sorted(p.stem for p in HDRI_DIR.glob("*.exr"))


def load_environment(env: spec.EnvironmentMap, field: str, base_dir: Path | None) -> np.ndarray:
    """The map of `env` as checked (H, W, 3) float32 linear radiance, before `env.scale` and `env.rotate`."""
    if env.procedural is not None:
        image, source = _procedural(env.procedural, env.params, field), f"{field}.procedural"
    else:
        if env.params:
            raise SceneError(f"{field}.params", "params apply only to procedural maps")
        if env.builtin is not None:
            source = f"{field}.builtin"
            names = builtin_environment_names()
            if env.builtin not in names:
                raise SceneError(source, f"unknown built-in map {env.builtin!r}; known: {', '.join(names)}")
            path = HDRI_DIR / f"{env.builtin}.exr"
        else:
            source = f"{field}.path"
            path = Path(env.path)
            if not path.is_absolute() and base_dir is not None:
                path = base_dir / path
            if not path.is_file():
                raise SceneError(source, f"environment map not found: {path}")
        check_exr_size(path, source)
        try:
            image = read_exr(path)
        except ValueError as error:
            raise SceneError(source, str(error)) from error
    return check_environment(image, source)


def _procedural(name: str, params: dict[str, Any], field: str) -> np.ndarray:
    if name not in PROCEDURAL_MAPS:
        known = ", ".join(sorted(PROCEDURAL_MAPS))
        raise SceneError(f"{field}.procedural", f"unknown procedural map {name!r}; known: {known}")
    params_model, build = PROCEDURAL_MAPS[name]
    return build(parse_params(params_model, params, f"{field}.params"))


def check_environment(image: np.ndarray, field: str) -> np.ndarray:
    """Reject what would poison importance sampling: wrong shape, NaN/Inf or clearly negative texels."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise SceneError(field, f"expected an (H, W, 3) lat-long image, got shape {image.shape}")
    image = image.astype(np.float32)
    finite = np.isfinite(image).all(axis=2)
    if not finite.all():
        row, column = np.argwhere(~finite)[0]
        raise SceneError(
            field, f"{int((~finite).sum())} NaN/Inf texels (first at row {row}, column {column})"
        )
    tolerance = NEGATIVE_RINGING * float(np.abs(image).mean())
    if image.min() < -tolerance:
        row, column = np.argwhere((image < -tolerance).any(axis=2))[0]
        raise SceneError(
            field, f"negative radiance {float(image.min()):.4g} (first at row {row}, column {column})"
        )
    return np.ascontiguousarray(np.maximum(image, 0.0))
