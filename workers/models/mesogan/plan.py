"""What a scene needs from mesogan: the surfaces the shell covers (by material name), the shell height,
the plane's resolution and mip levels implied by the surfaces' UV area and the closest view, the
networks' sizes, and the estimated cost.
"""

from __future__ import annotations

import math

import numpy as np

from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.covering import build_shell, covering
from workers.models.mesogan.sampling import cone_radius, widest_footprint
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import fixed_costs, report_view
from workers.scene.portability.reference import SceneRef

SECONDS_PER_IMAGE = 0.5  # path tracing one training view (quick sizes, one idle core)
SECONDS_PER_STEP_PER_VIEW = 0.02  # generator + discriminator phases per batch element at 16^2, 6 samples


def closest_view(compiled, triangles: np.ndarray, shell_height: float) -> tuple[float, float]:
    """The camera's distance to the closest covered vertex and a pixel's cone footprint there (slab
    heights): the narrowest footprint the shell is read at, and about the one of the whole surface when
    the mesh is small beside its distance."""
    camera = compiled.spec.camera
    covered = compiled.positions[triangles].reshape(-1, 3)
    closest = float(np.linalg.norm(covered - np.asarray(camera.position), axis=1).min())
    return closest, closest * cone_radius(camera.fov, camera.height) / shell_height


def plan(scene: SceneRef, config: MesoganConfig) -> Plan:
    compiled = scene.compiled()
    cover = covering(compiled, config.surfaces, config.shell_height, config.texel)
    build_shell(compiled, cover, config.shell_height)  # a degenerate or folding shell is refused here
    closest, footprint = closest_view(compiled, cover.triangles, config.shell_height)
    widest = widest_footprint(config)
    finest = max(0.0, math.log2(max(min(footprint, widest), 1e-12) / config.texel))
    levels = config.mip_levels
    wider = (
        f"; its footprint ({footprint:.2f} slab heights) is wider than the widest trained ({widest:.2f}): "
        "the decoder is read at that, and the path tracer's samples filter the rest (farther "
        "`coarse_distances` would filter it with the mip stack)"
        if footprint > widest
        else ""
    )
    pixels = config.image_size**2
    seconds = config.pool * SECONDS_PER_IMAGE * pixels / 256 * config.training_spp / 8
    seconds += config.train.steps * config.batch_size * SECONDS_PER_STEP_PER_VIEW * pixels / 256
    view = report_view(config.preview_size**2, config.evaluation_spp, config.reference_spp, config.max_depth)
    fixed = fixed_costs(scene, config, (view,))
    seconds += fixed.seconds
    items = [
        PlanItem(
            name="surfaces",
            choice=", ".join(n for n in config.surfaces if n in compiled.material_names),
            reason=f"{len(cover.triangles)} triangles covered by a shell of height {config.shell_height:g}",
        ),
        PlanItem(
            name="plane",
            choice=f"{cover.resolution}^2 x {config.plane_channels}, {levels} mip levels",
            reason=(
                f"the UV square spans {cover.plane_units:.1f} slab heights at {config.texel:g} per texel; "
                "the "
                f"closest view ({closest:.2f} away) reads level {finest:.1f} and coarser{wider}"
            ),
        ),
        PlanItem(
            name="networks",
            choice=(
                f"generator {config.generator_layers}x{config.generator_width}, decoder "
                f"{config.decoder.describe()}, discriminator {config.discriminator_width} wide"
            ),
            reason=f"{config.train.steps} GAN steps of {config.batch_size} views of {config.image_size}^2",
        ),
        fixed.item(),
    ]
    summary = (
        f"{config.material} shell over {len(cover.triangles)} triangles, plane {cover.resolution}^2; "
        f"about {seconds:.0f} s"
    )
    return Plan(items=items, estimated_seconds=seconds, summary=summary)
