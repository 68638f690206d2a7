"""A relit frame (Algorithm 1): G-buffer from a 1-spp raycast, the K wavelets of the lighting with the
largest area-weighted magnitude, B = sum_k L_k T_k from the network at every pixel that sees geometry
(pixels that see the environment get no indirect light: they are masked, not learned), plus direct light
path-traced at the first hit (next-event estimation and BSDF-sampled escapes: `max_depth` 2), which also
draws the environment where camera rays escape. With `denoise`, the direct light is rendered as two
independent halves of `spp` (their difference estimates its variance) and filtered by the G-buffer-guided
à-trous filter (`workers.render.denoise`): the paper denoises its direct light too (Sec. 6). With
`checkerboard`, the network runs at half the pixels (`checkerboard`)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from workers.models.prt.checkerboard import checkerboard as checkerboard_of
from workers.models.prt.gbuffer import SurfaceInputs, surface_inputs
from workers.models.prt.network import PrtNetwork
from workers.models.prt.selection import run_time_selection
from workers.models.prt.views import pixel_rays
from workers.render.denoise import LUMINANCE, Guides, atrous
from workers.render.integrator import PathTracer
from workers.render.render import RenderResult, RenderSettings, render
from workers.scene.format.spec import Camera

DIRECT_DEPTH = 2  # camera segment + one bounce: emitters seen, NEE and BSDF-sampled escapes at the first hit
SECOND_HALF_SEED = 1 << 20  # seed offset of the direct light's second half (independent of the first)
SAMPLER = "stratified"  # the direct light's (`RenderSettings.sampler`; the report's path tracing uses it too)


@dataclass
class Frame:
    image: np.ndarray  # (H, W, 3) float32: direct + indirect
    direct: np.ndarray
    indirect: np.ndarray
    seconds: float  # the whole frame
    network_seconds: float  # selection and network only
    rays: int  # traced: the G-buffer's and the direct light's (counted, the same on any machine)
    network_flops: int  # f's products over the shaded pixel-wavelet pairs (`PrtNetwork.pair_flops`)


def predict_indirect(
    model: PrtNetwork,
    inputs: SurfaceInputs,
    box: np.ndarray,
    objects: np.ndarray,
    cube: np.ndarray,
    k: int,
    weighting: str,
    checkerboard: tuple[int, int] | None = None,
) -> tuple[np.ndarray, int]:
    """Indirect radiance (N, 3) float32 of every pixel under `cube`: 0 where the camera ray escapes and on
    objects not modelled; and how many pixel-wavelet pairs the network shaded. With `checkerboard` the
    frame's (height, width), the network shades half of the pixels and the rest are filled from their
    neighbours (`checkerboard`)."""
    out = np.zeros((len(inputs.hit), 3), np.float32)
    modelled = inputs.modelled(objects)
    board = None if checkerboard is None else checkerboard_of(inputs, modelled, *checkerboard)
    seen = np.flatnonzero(modelled if board is None else board.shaded)
    if len(seen) == 0:
        return out, 0
    chosen = run_time_selection(cube, k, weighting)
    device = next(model.parameters()).device
    tensors = {name: t.to(device) for name, t in inputs.take(seen).tensors(box).items()}
    with torch.inference_mode():
        b = model(tensors, chosen.indices.to(device), chosen.values.float().to(device))
    out[seen] = b.float().cpu().numpy()
    return (out if board is None else board.fill(out)), len(seen) * len(chosen.indices)


def guides_of(inputs: SurfaceInputs, camera: Camera) -> Guides:
    """The denoiser's G-buffer from the frame's own pixel-centre raycast."""
    h, w = camera.height, camera.width
    position = inputs.position.reshape(h, w, 3)
    distance = np.linalg.norm(position - np.asarray(camera.position), axis=-1)
    pixel_angle = 2 * np.tan(np.radians(camera.fov) / 2) / h
    return Guides(
        mask=inputs.hit.reshape(h, w),
        normal=inputs.normal.reshape(h, w, 3),
        position=position,
        footprint=distance * pixel_angle,
        object_id=inputs.object_id.reshape(h, w),
        albedo=(inputs.kd + inputs.ks).reshape(h, w, 3),
    )


def direct_light(
    tracer: PathTracer,
    camera: Camera,
    inputs: SurfaceInputs,
    spp: int,
    seed: int,
    threads: int,
    denoise: bool,
) -> tuple[np.ndarray, int]:
    """The direct light (H, W, 3) at `spp` paths per pixel, denoised or not, and the rays it traced."""

    def half(samples: int, seed: int) -> RenderResult:
        settings = RenderSettings(
            spp=samples, width=camera.width, height=camera.height, max_depth=DIRECT_DEPTH, seed=seed,
            threads=threads, sampler=SAMPLER,
        )  # fmt: skip
        return render(tracer, settings, view=camera)

    if not denoise or spp < 2:
        whole = half(spp, seed)
        return whole.image, whole.rays_traced
    first, second = half(spp // 2, seed), half(spp - spp // 2, seed + SECOND_HALF_SEED)
    mean = (first.image * (spp // 2) + second.image * (spp - spp // 2)) / spp
    variance = ((first.image - second.image) @ LUMINANCE) ** 2 / 4  # of the mean of two equal halves
    image = atrous(mean, guides_of(inputs, camera), variance=variance)
    return image, first.rays_traced + second.rays_traced


def render_frame(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    tracer: PathTracer,
    cube: np.ndarray,
    camera: Camera,
    *,
    k: int,
    weighting: str,
    spp: int,
    seed: int = 0,
    threads: int = 1,
    denoise: bool = False,
    checkerboard: bool = False,
) -> Frame:
    """The frame through `camera`: `tracer` lights the scene for the direct light (its environment is the
    lighting, at whatever resolution) and `cube` is the same lighting as the network's cube map. `spp` is the
    direct light's paths per pixel (before denoising); `checkerboard` shades the indirect light at half the
    pixels."""
    start = time.perf_counter()
    origins, directions = pixel_rays(camera)
    inputs = surface_inputs(tracer, origins, directions)
    network_start = time.perf_counter()
    shape = (camera.height, camera.width)
    indirect, pairs = predict_indirect(
        model, inputs, box, objects, cube, k, weighting, shape if checkerboard else None
    )
    indirect = indirect.reshape(*shape, 3)
    network_seconds = time.perf_counter() - network_start
    direct, rays = direct_light(tracer, camera, inputs, spp, seed, threads, denoise)
    seconds = time.perf_counter() - start
    flops = pairs * model.pair_flops()
    return Frame(direct + indirect, direct, indirect, seconds, network_seconds, len(origins) + rays, flops)
