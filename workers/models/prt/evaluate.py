"""Held-out figures of a trained `prt` model (Table 1's layout): PSNR and SSIM of the full frame and of
the indirect light alone, and FLIP of the full frame, on near and far test views under lightings never
trained on. The ground truth is path-traced per lighting at `test_spp` with importance sampling of that
lighting: indirect as binned transport (`transport`, traced under the lighting's own sampler) dotted with
it, direct as a render. Rows traced once with the lighting-independent sampler would serve every lighting,
but under a sun they are far noisier: at 64 spp their indirect was 15-25 dB PSNR from a 1024-spp reference
on env_lit_objects, which capped what a perfect model could score. The model's frame is its own
path-traced direct light at `held_out_spp`, denoised, plus predicted indirect at every pixel (`frame`). The
trivial baseline is the same direct light with no indirect at all."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workers.models.prt.config import PrtConfig
from workers.models.prt.data import TestView, cameras, test_views
from workers.models.prt.frame import DIRECT_DEPTH, SAMPLER, Frame, render_frame
from workers.models.prt.lighting import held_out_lightings, lighting_cube, relit_tracer, unit_mean
from workers.models.prt.network import PrtNetwork
from workers.models.prt.transport import trace_rows
from workers.models.prt.views import FAR, NEAR, TRAIN, pixel_rays
from workers.nn.metrics import flip, psnr, ssim
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.view import PathTracedView
from workers.scene.format.spec import Camera
from workers.scene.portability.reference import SceneRef

TRUTH_SEED = 1000  # the direct ground truth's noise is independent of the frame's


@dataclass
class Case:
    view: str
    lighting: str
    truth_full: np.ndarray
    truth_indirect: np.ndarray
    frame: Frame

    def figures(self) -> dict[str, float]:
        no_indirect = np.zeros_like(self.truth_indirect)
        return {
            "psnr_full": psnr(self.truth_full, self.frame.image),
            "psnr_indirect": psnr(self.truth_indirect, self.frame.indirect),
            "ssim_full": ssim(self.truth_full, self.frame.image),
            "ssim_indirect": ssim(self.truth_indirect, self.frame.indirect),
            "flip_full": flip(self.truth_full, self.frame.image),
            "baseline_psnr_full": psnr(self.truth_full, self.frame.direct),
            "baseline_psnr_indirect": psnr(self.truth_indirect, no_indirect),
            "baseline_flip_full": flip(self.truth_full, self.frame.direct),
            "seconds_per_frame": self.frame.seconds,
        }


def truth(
    view: TestView, cube: np.ndarray, tracer: PathTracer, spp: int, seed: int, max_depth: int
) -> tuple[np.ndarray, np.ndarray]:
    """The view's full and indirect images (H, W, 3) float32 under cube map `cube` (`tracer` renders it)."""
    camera = view.camera
    rng = np.random.default_rng([seed, TRUTH_SEED])
    rows = trace_rows(tracer, *pixel_rays(camera), spp, cube.shape[1], rng, max_depth)
    indirect = rows.radiance(cube, ("indirect",)).reshape(camera.height, camera.width, 3)
    settings = RenderSettings(
        spp=spp, width=camera.width, height=camera.height, max_depth=DIRECT_DEPTH, seed=seed + TRUTH_SEED
    )
    direct = render(tracer, settings, view=camera).image
    return (direct + indirect).astype(np.float32), indirect.astype(np.float32)


def held_out_cases(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    scene: SceneRef,
    config: PrtConfig,
    seed: int,
    k: int | None = None,
) -> list[Case]:
    """Every (test view, held-out lighting) pair, lightings at unit mean radiance."""
    cases = []
    views = test_views(scene, config, seed)
    for name, env in held_out_lightings(config.lighting, seed).items():
        cube = unit_mean(lighting_cube(env, config.cube_size, config.lighting.map_width))
        tracer = relit_tracer(scene.compiled(), cube)
        for view in views:
            full, indirect = truth(view, cube, tracer, config.test_spp, seed, config.max_depth)
            frame = held_out_frame(model, box, objects, tracer, cube, view.camera, config, seed, k)
            cases.append(Case(view.name, name, full, indirect, frame))
    return cases


def held_out_frame(
    model: PrtNetwork,
    box: np.ndarray,
    objects: np.ndarray,
    tracer: PathTracer,
    cube: np.ndarray,
    camera: Camera,
    config: PrtConfig,
    seed: int,
    k: int | None = None,
) -> Frame:
    """The frame the held-out figures measure: the direct light at `held_out_spp`, denoised, and the
    network at every pixel, so that the full frame's error is mostly the network's (not the artifact's
    frame, which trades error for time: `evaluation_spp`, `checkerboard`)."""
    return render_frame(
        model, box, objects, tracer, cube, camera, k=k or config.wavelets, weighting=config.selection,
        spp=config.held_out_spp, seed=seed, denoise=True,
    )  # fmt: skip


@dataclass
class ReportView:
    """The view the report measures the model on: a far (else near, else training) view under the first
    held-out lighting, `cube` as the network's cube map and `view` as path tracing of it (curve and
    reference)."""

    camera: Camera
    lighting: str
    cube: np.ndarray
    tracer: PathTracer
    view: PathTracedView


def report_view(scene: SceneRef, config: PrtConfig, seed: int) -> ReportView:
    views = cameras(scene, config)
    camera = (views[FAR] or views[NEAR] or views[TRAIN])[0]
    name, env = next(iter(held_out_lightings(config.lighting, seed).items()))
    cube = unit_mean(lighting_cube(env, config.cube_size, config.lighting.map_width))
    compiled = scene.compiled()
    at_view = replace(compiled, spec=compiled.spec.model_copy(update={"camera": camera}))
    tracer = relit_tracer(at_view, cube)
    settings = RenderSettings(  # spp 1: the curve and the reference set their own
        spp=1, width=camera.width, height=camera.height, max_depth=config.max_depth, seed=seed, threads=1,
        sampler=SAMPLER,
    )  # fmt: skip
    view = PathTracedView(at_view, settings, config.reference_spp, tracer)
    return ReportView(camera, name, cube, tracer, view)


def summarise(cases: list[Case]) -> dict[str, float]:
    """Means over all cases, over near and far views apart (`near.psnr_full`, ...) and per lighting
    (`sunset.psnr_full`, ...)."""
    out: dict[str, float] = {}
    groups = {"": cases}
    for split in ("near", "far"):
        chosen = [c for c in cases if c.view.startswith(split)]
        if chosen:
            groups[f"{split}."] = chosen
    for lighting in dict.fromkeys(c.lighting for c in cases):
        groups[f"{lighting}."] = [c for c in cases if c.lighting == lighting]
    for prefix, group in groups.items():
        figures = [c.figures() for c in group]
        for key in figures[0]:
            out[f"{prefix}{key}"] = float(np.mean([f[key] for f in figures]))
    return out
