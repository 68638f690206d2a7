"""The network's frames and their error against path tracing, at fixed configurations of the scene.

A frame is what serving does: Embree G-buffers through pixel centres, then the network per pixel; its time
covers both. Errors are DSSIM and MAPE (thesis Sec. 5.6: 1 - SSIM over 2 on the sRGB-tonemapped image,
|t - r| / (r + 0.01)) against path tracing at `reference_spp`.

The path tracer averages radiance over each pixel's area (jittered samples); the network reads G-buffers
at single points. Measured at pixel centres, even a perfect network is off at every edge: 256 spp traced
through pixel centres scored DSSIM 0.063 against the 1024-spp reference on `cornell_variable`'s 32^2
views (jittered 256 spp: 0.010), which is where every network trained in minutes sat (0.068-0.071), so
errors were flat across configurations. The measured frames therefore average `ANTIALIASING`^2 pixel
centres per pixel, as the reference's box filter does (4 x 4 centres at 256 spp: 0.013).
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
from workers.scene.spec import Camera

PIXELS_PER_CHUNK = 1 << 16
ANTIALIASING = 4  # network samples per pixel side in the measured frames


def configurations(dimensions: int, count: int, seed: int) -> np.ndarray:
    """`count` fixed scene vectors: the middle of every range, then seeded uniform draws."""
    rng = np.random.default_rng([seed, 0x5EED])
    return np.concatenate([np.full((1, dimensions), 0.5), rng.random((count - 1, dimensions))])[:count]


@torch.no_grad()
def network_image(
    model: PixelGenerator, tracer: PathTracer, camera: Camera, box: np.ndarray, v: np.ndarray,
    width: int, height: int, antialiasing: int = 1,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """(H, W, 3) linear radiance of the view at v, and the seconds it took (G-buffers and network); each
    pixel the mean of `antialiasing`^2 pixel centres of a finer frame, traced and run in bands of rows of
    about `PIXELS_PER_CHUNK` samples, so memory does not grow with the frame."""
    started = time.perf_counter()
    s = antialiasing
    fine = PinholeCamera(camera, width * s, height * s)
    device = next(model.parameters()).device
    image = np.empty((height, width, 3), np.float32)
    rows = max(1, PIXELS_PER_CHUNK // (width * s * s))  # output rows a band
    with torch_threads(1):  # small layers: a second thread busy-waits (`workers.runtime.threads`)
        for y0 in range(0, height, rows):
            y1 = min(height, y0 + rows)
            buffers = primary_gbuffers(tracer, fine, (0, y0 * s, width * s, y1 * s))
            features = torch.from_numpy(pixel_features(buffers, box, v)).reshape(-1, 13 + len(v))
            emission = torch.from_numpy(buffers.emission).reshape(-1, 3)
            radiance = model.radiance(features.to(device), emission.to(device)).float().cpu().numpy()
            image[y0:y1] = radiance.reshape(y1 - y0, s, width, s, 3).mean(axis=(1, 3))
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
    settings = RenderSettings(spp=spp, width=size, height=size, max_depth=max_depth, seed=seed, threads=2)
    return [render(t, settings).image for t in tracers]


def configuration_errors(
    model: PixelGenerator, tracers: list[PathTracer], vectors: np.ndarray, references: list[np.ndarray],
    box: np.ndarray,
) -> ConfigurationErrors:  # fmt: skip
    errors = ConfigurationErrors([], [])
    for tracer, v, reference in zip(tracers, vectors, references, strict=True):
        h, w = reference.shape[:2]
        image, _ = network_image(model, tracer, tracer.scene.spec.camera, box, v, w, h, ANTIALIASING)
        errors.dssim.append(dssim(reference, image))
        errors.mape.append(mape(reference, image))
    return errors
