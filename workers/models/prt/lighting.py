"""Lightings as cube maps: from a scene-style `EnvironmentMap` (a built-in HDRI, a procedural map, an
uploaded lat-long image) to the 6 x R^2 cube the network's wavelets index, the training distribution and
the held-out set, and the environment light that renders a cube map exactly as its wavelets see it.

Convention (Sec. 3, Ng et al. 2003): texels are not weighted by their solid angle before the Haar
transform; the transport absorbs it. The light a cube map is, is its nearest texel in every direction:
`CubeMapLight` looks texels up that way, and `workers.models.prt.transport` bins escapes the same way, so
"bin, then dot with L" and "render under L" are the same sum.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import torch

from workers.models.prt.config import LightingConfig
from workers.nn.cubemap import FACE_FRAMES, cubemap_directions, latlong_to_cubemap
from workers.render.integrator import PathTracer
from workers.render.jit import njit
from workers.render.sampling import luminance
from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators.envmaps import (
    HDRI_DIR,
    PROCEDURAL_MAPS,
    check_environment,
    load_environment,
    uv_to_direction,
)
from workers.scene.geometry.compile import CompiledScene
from workers.scene.importers.image_io import read_exr

PROCEDURAL = tuple(PROCEDURAL_MAPS)  # sky, studio
SAMPLING_FLOOR = 1e-3  # share of the mean radiance every texel keeps for importance sampling (no zero pdf)


def downsampled(latlong: np.ndarray, width: int) -> np.ndarray:
    """Box-filter a lat-long map to `width` x `width / 2` when it is larger: texel means keep the energy of
    a sun that bilinear taps at the cube's resolution would miss."""
    height_in, width_in = latlong.shape[:2]
    factor = width_in // width
    if factor <= 1 or width_in % width or height_in % factor:
        return latlong
    return latlong.reshape(height_in // factor, factor, width_in // factor, factor, 3).mean(axis=(1, 3))


@cache
def _builtin_hdri(name: str, width: int) -> np.ndarray:
    return downsampled(read_exr(HDRI_DIR / f"{name}.exr").astype(np.float64), width)


def latlong_of(
    env: spec.EnvironmentMap, width: int, field: str = "lighting", upload: np.ndarray | None = None
):
    """The lat-long map (H, W, 3) float64 of `env` (scaled, not rotated) at about `width` texels across,
    and its rotation (local -> world). An uploaded map stands in for `env.path`; SceneError names `field`
    for unknown names, bad parameters and NaN/Inf texels."""
    if env.path is not None:
        if upload is None:
            raise SceneError(f"{field}.path", "upload the lat-long EXR as the `environment` array instead")
        image = check_environment(np.asarray(upload), f"{field}.path").astype(np.float64)
        image = downsampled(image, width)
    elif env.builtin is not None and not env.params:
        known = sorted(p.stem for p in HDRI_DIR.glob("*.exr"))
        if env.builtin not in known:
            raise SceneError(
                f"{field}.builtin", f"unknown built-in map {env.builtin!r}; known: {', '.join(known)}"
            )
        image = _builtin_hdri(env.builtin, width)
    else:
        if env.procedural is not None and "width" not in env.params:
            env = env.model_copy(update={"params": {"width": width, "height": width // 2, **env.params}})
        image = load_environment(env, field, None).astype(np.float64)
    return image * env.scale, spec.euler_xyz(env.rotate)


def cube_of(latlong: np.ndarray, rotation: np.ndarray, size: int) -> np.ndarray:
    """The cube map [6, R, R, 3] float64 of a lat-long map turned by `rotation` (local -> world)."""
    cube = latlong_to_cubemap(
        torch.from_numpy(np.ascontiguousarray(latlong)), size, rotation=torch.from_numpy(rotation)
    )
    return cube.numpy()


def lighting_cube(env: spec.EnvironmentMap, size: int, width: int, field: str = "lighting", upload=None):
    return cube_of(*latlong_of(env, width, field, upload), size)


# ------------------------------------------------------------------ training and held-out lightings


def _procedural(rng: np.random.Generator, name: str) -> spec.EnvironmentMap:
    if name == "sky":
        params = {
            "sun_elevation": float(rng.uniform(5.0, 75.0)),
            "sun_azimuth": float(rng.uniform(0.0, 360.0)),
            "sun_irradiance": float(rng.uniform(5.0, 40.0)),
        }
    else:
        params = {"seed": int(rng.integers(0, 2**62)), "lights": int(rng.integers(2, 8))}
    return spec.EnvironmentMap(procedural=name, params=params)


def training_lighting(config: LightingConfig, rng: np.random.Generator) -> spec.EnvironmentMap:
    """One lighting of the training distribution (the class docstring of `LightingConfig`)."""
    if rng.random() < config.procedural_fraction:
        env = _procedural(rng, PROCEDURAL[int(rng.integers(len(PROCEDURAL)))])
    else:
        env = spec.EnvironmentMap(builtin=config.train_hdris[int(rng.integers(len(config.train_hdris)))])
    return env.model_copy(update={"rotate": (0.0, float(rng.uniform(0.0, 360.0)), 0.0)})


HELD_OUT_STREAM = 2**40  # procedural test maps come from seeds training never draws


def unit_mean(cube: np.ndarray) -> np.ndarray:
    """The cube map scaled to mean luminance 1 (a black map stays black): B is linear in L, so this only
    balances lightings against each other (in the loss, and where the targets' smoothing is judged)."""
    mean = float(luminance(cube.reshape(-1, 3)).mean())
    return cube / mean if mean > 0 else cube


def held_out_lightings(config: LightingConfig, seed: int) -> dict[str, spec.EnvironmentMap]:
    """The test lightings by name: each held-out HDRI, then procedural maps alternating sky and studio."""
    out = {name: spec.EnvironmentMap(builtin=name) for name in config.test_hdris}
    for i in range(config.test_procedural):
        name = PROCEDURAL[i % len(PROCEDURAL)]
        rng = np.random.default_rng([seed, HELD_OUT_STREAM, i])
        out[f"{name}_{i}"] = _procedural(rng, name).model_copy(
            update={"rotate": (0.0, float(rng.uniform(0.0, 360.0)), 0.0)}
        )
    return out


# ------------------------------------------------------------------ rendering under a cube map


class CubeMapLight:
    """An environment light whose radiance is the nearest texel of a cube map [6, R, R, 3].

    Directions are importance-sampled by `sampler` (any environment light of the path tracer whose pdf is
    positive wherever the cube is): the estimate stays unbiased whatever the sampler, so a tracer can swap
    the cube it renders under and keep the very same paths."""

    def __init__(self, cube: np.ndarray, sampler) -> None:
        self.cube = np.ascontiguousarray(cube, dtype=np.float64)
        self.size = self.cube.shape[1]
        self.flat = self.cube.reshape(-1, 3)
        self.sampler = sampler
        self.mean_radiance = sampler.mean_radiance

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        return self.flat[texels_of(directions, self.size)]

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.sampler.sample(u)

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        return self.sampler.pdf(directions)


def texels_of(directions: np.ndarray, size: int) -> np.ndarray:
    """Flat cube texel index of each direction (N, 3), nearest texel: `direction_to_texel`'s, compiled (in
    torch it was a fifth of the CPU time of prt's direct light and of path tracing under a cube map)."""
    return _texels(np.ascontiguousarray(directions, dtype=np.float64), size, FACE_FRAMES_NP)


FACE_FRAMES_NP = FACE_FRAMES.numpy()  # each face's (major axis, s axis, t axis), for the compiled lookup


@njit(cache=True, nogil=True)
def _texels(directions, size, frames):
    out = np.empty(len(directions), np.int64)
    for i in range(len(directions)):
        axis = 0  # the first largest |component|, as torch's argmax
        for a in range(1, 3):
            if abs(directions[i, a]) > abs(directions[i, axis]):
                axis = a
        major = directions[i, axis]
        face = 2 * axis + (1 if major < 0 else 0)
        scale = max(abs(major), 1e-30)
        texel = face
        for row in (2, 1):  # t picks the row, s the column
            dot = 0.0
            for a in range(3):
                dot += directions[i, a] * frames[face, row, a]
            st = min(max((dot / scale + 1) / 2, 0.0), 1.0)
            texel = texel * size + min(max(int(st * size), 0), size - 1)
        out[i] = texel
    return out


def sampling_latlong(cube: np.ndarray, height: int | None = None) -> np.ndarray:
    """A lat-long picture (H, 2H, 3) of the cube's nearest texels plus a small floor: what importance
    sampling follows (the floor keeps the pdf positive where a lat-long texel centre misses a lit texel)."""
    size = cube.shape[1]
    height = height or 4 * size
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(2 * height) + 0.5) / (2 * height)
    directions = uv_to_direction(u[None, :], v[:, None]).reshape(-1, 3)
    image = cube.reshape(-1, 3)[texels_of(directions, size)].reshape(height, 2 * height, 3)
    floor = SAMPLING_FLOOR * max(float(luminance(image).mean()), 1e-12)
    return image + floor


def relit_tracer(scene: CompiledScene, cube: np.ndarray, **kwargs) -> PathTracer:
    """A path tracer of `scene` whose environment is exactly `cube` (`CubeMapLight`), importance-sampled
    from `sampling_latlong(cube)`; the scene's own lights and emitters stay."""
    lit = replace(
        scene, environment_image=sampling_latlong(cube).astype(np.float32), environment_rotation=np.eye(3)
    )
    tracer = PathTracer(lit, **kwargs)
    tracer.lights.environment = CubeMapLight(cube, tracer.lights.environment)
    return tracer


def uniform_cube(size: int) -> np.ndarray:
    """A white cube map: the lighting transport rows are traced under (its sampler is near-uniform)."""
    return np.ones((6, size, size, 3))


def cube_directions(size: int) -> np.ndarray:
    return cubemap_directions(size, torch.float64).numpy().reshape(-1, 3)
