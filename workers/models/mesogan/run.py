"""The `mesogan` method on the shared pipeline: one GAN (discriminator and generator phases) trained on
path-traced slab views, exported, then measured on the scene: the scene's covered surfaces rendered with
the neural shell against the same surfaces covered by real strands and path-traced (the report's view).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from workers.models.mesogan import artifact
from workers.models.mesogan.aggregate import ShellAggregate
from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.covering import build_shell, covering, neural_material, with_strands
from workers.models.mesogan.evaluate import generation_scores, held_out_views, structure_response
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig, cone_radius
from workers.models.mesogan.shell import Shell
from workers.models.mesogan.train import phases
from workers.nn.metrics import flip
from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.report import TimedImage
from workers.runtime.sources import SourceSpec
from workers.runtime.view import PathTracedView
from workers.scene.format.spec import Camera

TRIANGLE_BYTES = 3 * 3 * 4 + 3 * 3 * 4 + 3 * 2 * 4 + 64  # positions, normals, UVs and BVH share, float32


def covered_pixels(shell: Shell, camera: Camera, size: int) -> np.ndarray:
    """(size, size) mask of the pixels whose centre ray meets the shell."""
    pinhole = PinholeCamera(camera, size, size)
    py, px = np.mgrid[0:size, 0:size] + 0.5
    origins, directions = pinhole.rays(px.ravel(), py.ravel())
    n = len(origins)
    hit = np.zeros(n, bool)
    hit[shell.intervals(origins, directions, np.zeros(n), np.full(n, np.inf)).ray] = True
    return hit.reshape(size, size)


class MesoganMethod:
    kind = "mesogan"

    def trainables(self, ctx: JobContext[MesoganConfig]) -> list[Trainable]:
        config = ctx.config
        covering(ctx.scene.compiled(), config.surfaces, config.shell_height, config.texel)  # fail early
        spec = SourceSpec(SlabSource, SlabSourceConfig(mesogan=config), ctx.seed)
        torch.manual_seed(ctx.seed)
        model = MesoGAN(config)
        return [Trainable(model, phases(model), spec, config.train, stored_dtype=artifact.STORAGE_DTYPE)]

    def finish(self, ctx: JobContext[MesoganConfig], trained: list[Trained]) -> Finished:
        config = ctx.config
        model: MesoGAN = trained[0].model
        files = artifact.save(ctx.output_dir, config, model, ctx.scene.spec, ctx.scene.local_folder())
        scene = ctx.scene.compiled()
        cover = covering(scene, config.surfaces, config.shell_height, config.texel)
        shell = build_shell(scene, cover, config.shell_height)
        ctx.raise_if_cancelled()
        strands = with_strands(scene, cover, config, config.structure, config.appearance, ctx.seed)
        settings = RenderSettings(
            spp=config.evaluation_spp, width=config.preview_size, height=config.preview_size,
            max_depth=config.max_depth, seed=ctx.seed, threads=1,
        )  # fmt: skip
        view = PathTracedView(strands, settings, config.reference_spp)
        started = time.perf_counter()
        material = neural_material(model, config, cover, config.structure, config.appearance, ctx.seed)
        generate_seconds = time.perf_counter() - started
        camera = scene.spec.camera
        cone = cone_radius(camera.fov, config.preview_size)
        aggregate = ShellAggregate(shell, material, config.samples_per_ray, cone)
        ctx.log(f"rendering {config.preview_size}^2 with the neural shell at {config.evaluation_spp} spp")
        result = render(PathTracer(scene, aggregate=aggregate), settings)
        frame = TimedImage(f"{config.evaluation_spp} spp", result.image, result.seconds)
        covered = covered_pixels(shell, camera, config.preview_size)
        reference = view.reference()
        source: SlabSource = trained[0].trainable.source.build()
        scores = generation_scores(model, held_out_views(source, config.evaluation_instances))
        strand_triangles = strands.num_triangles - scene.num_triangles
        model_bytes = artifact.shipped_bytes(model)
        plane_bytes = sum(level.numel() * 2 for level in material.stack)
        method_metrics = {
            **{f"held_out_{k}": v for k, v in scores.items()},
            **structure_response(model, source, config.evaluation_instances),
            # the frame's error where the shell is seen, against path tracing there at 1 spp
            "flip_covered_pixels": flip(reference, result.image, mask=covered),
            "flip_covered_pixels_path_tracing_1spp": flip(reference, view.frame(1).image, mask=covered),
            "covered_pixel_fraction": float(covered.mean()),
            "covered_triangles": float(len(cover.triangles)),
            "plane_resolution": float(cover.resolution),
            "plane_seconds": generate_seconds,
            "model_bytes": float(model_bytes),
            "plane_bytes": float(plane_bytes),
            "strand_triangles": float(strand_triangles),
            "strand_bytes": float(strand_triangles * TRIANGLE_BYTES),
            "strand_to_model_bytes": strand_triangles * TRIANGLE_BYTES / (model_bytes + plane_bytes),
            "density_queries_per_pixel_sample": aggregate.density_queries
            / (config.preview_size**2 * config.evaluation_spp),
        }
        metrics = {
            "model_bytes": float(model_bytes),
            "strand_triangles": float(strand_triangles),
            "held_out_swd": scores["swd"],
        }
        return Finished(files, view, frame, method_metrics, metrics)
