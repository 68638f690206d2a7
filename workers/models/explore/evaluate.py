"""The network's frames and their error against path tracing, at fixed configurations of the scene.

A frame is what serving does: Embree G-buffers through pixel centres, then the network per pixel; its time
covers both. Errors are DSSIM and MAPE (thesis Sec. 5.6: 1 - SSIM over 2 on the sRGB-tonemapped image,
|t - r| / (r + 0.01)) against path tracing at `reference_spp`.

The path tracer averages radiance over each pixel's area (jittered samples); the network reads G-buffers
at single points. Measured at pixel centres, even a perfect network is off at every edge: 256 spp traced
through pixel centres scored DSSIM 0.063 against the 1024-spp reference on `cornell_variable`'s 32^2
views (jittered 256 spp: 0.010), which is where every network trained in minutes sat (0.068-0.071), so
errors were flat across configurations. The measured frames therefore average `ANTIALIASING`^2 pixel
centres per pixel, as the reference's box filter does (4 x 4 centres at 256 spp: 0.013); served frames
average 4 rotated-grid points (`RGSS`), nearly as close at a third of the time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from workers.models.explore.features import pixel_features
from workers.models.explore.network import PixelGenerator
from workers.nn.metrics import dssim, mape
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.threads import torch_threads
from workers.scene.format.spec import Camera

PIXELS_PER_CHUNK = 1 << 16
ANTIALIASING = 4  # network samples per pixel side in the measured frames
# Rotated-grid supersampling: 4 points per pixel whose x and y are all distinct (a 4-rooks pattern), so
# near-horizontal and near-vertical edges get 4 levels as with a 4 x 4 grid. On cornell_variable's 8 hard
# configurations (32^2, a network of 60 CPU s; CPU time, one thread, explore8): DSSIM 0.0243 at 7.0 ms a
# frame against 0.0219 at 22.6 ms for 4 x 4 (2 x 2: 0.0296 at 8.0 ms; 3 x 3: 0.0260 at 12.9 ms; pixel
# centres: 0.0565 at 3.3 ms); path tracing to the same DSSIM costs 13.8x the RGSS frame, 5.0x the 4 x 4.
# mirror_variable: RGSS 0.0737 at 6.6 ms, 4 x 4 0.0677 at 24.5 ms; path tracing 31.9x and 10.3x
RGSS = "rgss"
RGSS_OFFSETS = np.array([[0.125, 0.375], [0.375, 0.875], [0.625, 0.125], [0.875, 0.625]])
Antialiasing = int | str  # samples per pixel side on a grid, or RGSS


def pixel_offsets(antialiasing: Antialiasing) -> np.ndarray:
    """(n, 2) sample points in a pixel, from its corner: the s x s grid's centres, or RGSS's 4."""
    if antialiasing == RGSS:
        return RGSS_OFFSETS
    if not isinstance(antialiasing, int) or antialiasing < 1:
        raise ValueError(f"antialiasing: {antialiasing!r} is neither a grid side >= 1 nor {RGSS!r}")
    centres = (np.arange(antialiasing) + 0.5) / antialiasing
    y, x = np.meshgrid(centres, centres, indexing="ij")
    return np.stack([x.ravel(), y.ravel()], axis=-1)


def configurations(dimensions: int, count: int, seed: int) -> np.ndarray:
    """`count` fixed scene vectors: the middle of every range, then seeded uniform draws."""
    rng = np.random.default_rng([seed, 0x5EED])
    return np.concatenate([np.full((1, dimensions), 0.5), rng.random((count - 1, dimensions))])[:count]


@torch.no_grad()
def network_image(
    model: PixelGenerator, tracer: PathTracer, camera: Camera, box: np.ndarray, v: np.ndarray,
    width: int, height: int, antialiasing: Antialiasing = 1, mirror_bounces: int = 0,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """(H, W, 3) linear radiance of the view at v, and the seconds it took (G-buffers and network); each
    pixel the mean of the network at its `antialiasing` sample points (`pixel_offsets`), traced and run in
    bands of rows of about `PIXELS_PER_CHUNK` samples, so memory does not grow with the frame. Through
    `mirror_bounces` mirrors, the network's radiance is scaled by the mirrors' throughput."""
    started = time.perf_counter()
    offsets = pixel_offsets(antialiasing)
    n = len(offsets)
    pinhole = PinholeCamera(camera, width, height)
    device = next(model.parameters()).device
    image = np.empty((height, width, 3), np.float32)
    rows = max(1, PIXELS_PER_CHUNK // (width * n))  # output rows a band
    with torch_threads(1):  # small layers: a second thread busy-waits (`workers.runtime.threads`)
        for y0 in range(0, height, rows):
            y1 = min(height, y0 + rows)
            buffers = primary_gbuffers(tracer, pinhole, (0, y0, width, y1), offsets, mirror_bounces)
            features = torch.from_numpy(pixel_features(buffers, box, v)).reshape(-1, 13 + len(v))
            emission = torch.from_numpy(buffers.emission).reshape(-1, 3)
            radiance = model.radiance(features.to(device), emission.to(device)).float().cpu().numpy()
            radiance *= buffers.throughput.reshape(-1, 3)
            image[y0:y1] = radiance.reshape(y1 - y0, width, n, 3).mean(axis=2)
    return image, time.perf_counter() - started


@dataclass
class ConfigurationErrors:
    dssim: list[float]
    mape: list[float]

    def means(self) -> dict[str, float]:
        return {"dssim": float(np.mean(self.dssim)), "mape": float(np.mean(self.mape))}


def reference_images(
    tracers: list[PathTracer], size: int, spp: int, max_depth: int, seed: int
) -> list[np.ndarray]:
    """Path tracing of each configuration's view at `spp` (the converged images errors are taken against)."""
    settings = RenderSettings(spp=spp, width=size, height=size, max_depth=max_depth, seed=seed)
    return [render(t, settings).image for t in tracers]


def configuration_errors(
    model: PixelGenerator, tracers: list[PathTracer], vectors: np.ndarray, references: list[np.ndarray],
    box: np.ndarray, mirror_bounces: int = 0,
) -> ConfigurationErrors:  # fmt: skip
    errors = ConfigurationErrors([], [])
    for tracer, v, reference in zip(tracers, vectors, references, strict=True):
        h, w = reference.shape[:2]
        camera = tracer.scene.spec.camera
        image, _ = network_image(model, tracer, camera, box, v, w, h, ANTIALIASING, mirror_bounces)
        errors.dssim.append(dssim(reference, image))
        errors.mape.append(mape(reference, image))
    return errors
