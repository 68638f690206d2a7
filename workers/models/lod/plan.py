"""What a scene needs from `lod`: which objects are prefiltered, which LoDs are built, and how big.

The asset is every named object (or, by default, every non-emitting object of at least `min_triangles`):
small parts and emitters stay on Embree. LoDs: with `view_distances`, only the levels whose voxels are
about one pixel at one of those distances (the scene camera's vertical fov and height); without, every
level from `finest_resolution` down to `coarsest_resolution`. Empty voxels are never stored or trained.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from workers.models.lod.config import LodConfig, NetworkConfig
from workers.render.voxels import padded_bounds
from workers.runtime.contract import Plan, PlanItem
from workers.runtime.fixed_costs import Evaluation, fixed_costs, report_view
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Camera, SceneSpec
from workers.scene.geometry.mesh import MeshData
from workers.scene.portability.reference import SceneRef

TRAINING_SAMPLES_PER_SECOND = 60_000.0  # voxel samples per second, one idle 2-core CPU, default sizes
# quick menger_sponge: 24,128 occupied voxels x 64 samples took 1.3-3.0 s at loads 6-7 (0.5-1.2M a second);
# the estimate bounds the occupied voxels from above (37,376 there). 300k a second planned 8 s.
THRESHOLD_SAMPLES_PER_SECOND = 800_000.0


@dataclass(frozen=True)
class ObjectChoice:
    name: str
    prefiltered: bool
    triangles: int
    reason: str


@dataclass(frozen=True)
class Asset:
    """The objects to prefilter, their world bounds and the size of their meshes as stored."""

    choices: list[ObjectChoice]
    bounds: np.ndarray  # (2, 3)
    mesh_bytes: int

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.choices if c.prefiltered]

    @property
    def triangles(self) -> int:
        return sum(c.triangles for c in self.choices if c.prefiltered)


def mesh_bytes(mesh: MeshData) -> int:
    """A binary indexed mesh: float32 positions (normals, UVs when present) and uint32 indices."""
    per_vertex = 12 + (12 if mesh.normals is not None else 0) + (8 if mesh.uvs is not None else 0)
    return len(mesh.vertices) * per_vertex + 12 * len(mesh.faces)


def choose_asset(scene: SceneRef, config: LodConfig) -> Asset:
    """The objects to prefilter, from the compiled scene (its meshes read from the scene's folder)."""
    if config.objects is not None:
        unknown = sorted(set(config.objects) - {o.name for o in scene.spec.objects})
        if unknown:
            raise SceneError(
                "config.objects", f"no object named {', '.join(map(repr, unknown))} in the scene"
            )
    choices, corners, size = [], [], 0
    for obj, geometry in zip(scene.spec.objects, scene.compiled().objects, strict=True):
        mesh, matrices = geometry.mesh, geometry.instance_matrices
        triangles = mesh.num_triangles * len(matrices)
        if obj.emission is not None:
            chosen, reason = False, "emits light: light sampling needs its triangles"
        elif config.objects is not None:
            chosen = obj.name in config.objects
            reason = "named in config.objects" if chosen else "not named in config.objects"
        elif triangles < config.min_triangles:
            chosen, reason = False, f"{triangles} triangles < {config.min_triangles}: cheaper to trace as is"
        else:
            chosen, reason = True, f"{triangles} triangles >= {config.min_triangles}"
        if chosen and triangles == 0:
            chosen, reason = False, "has no triangles"
        if chosen:
            size += mesh_bytes(mesh)  # instances share one mesh
            for m in matrices:
                corners.append(mesh.vertices[mesh.faces.reshape(-1)] @ m[:3, :3].T + m[:3, 3])
        choices.append(ObjectChoice(obj.name, chosen, triangles, reason))
    if not corners:
        raise SceneError(
            "config.objects", "nothing to prefilter: no non-emitting object with triangles chosen"
        )
    points = np.concatenate(corners)
    return Asset(choices, np.stack([points.min(0), points.max(0)]), size)


def cube_extent(bounds: np.ndarray, finest: int) -> float:
    """Side of the grid's cube around the asset (as `LodGrid.build` pads it)."""
    padded = padded_bounds(bounds, finest)
    return float((padded[1] - padded[0]).max())


def choose_resolutions(scene: SceneSpec, config: LodConfig, extent: float) -> list[tuple[int, str]]:
    """(resolution, why) of every LoD to build, finest first."""
    allowed = config.resolutions
    if not config.view_distances:
        return [(r, "every LoD (no view_distances given)") for r in allowed]
    wanted: dict[int, list[float]] = {}
    for distance in config.view_distances:
        wanted.setdefault(resolution_at(scene.camera, distance, extent, allowed), []).append(distance)
    return [
        (r, f"a voxel is about a pixel at distance {', '.join(f'{d:g}' for d in wanted[r])}")
        for r in allowed
        if r in wanted
    ]


def resolution_at(camera: Camera, distance: float, extent: float, allowed: list[int]) -> int:
    """The resolution of `allowed` nearest (in octaves) to the one whose voxel, in a cube of side `extent`,
    covers about one pixel of `camera` at `distance`."""
    footprint = 2 * distance * math.tan(math.radians(camera.fov) / 2) / camera.height
    ideal = extent / max(footprint, 1e-300)
    return min(allowed, key=lambda r: abs(math.log2(r) - math.log2(max(ideal, 1e-300))))


def parameter_count(
    size: NetworkConfig, octaves: int, coarsest: int, n_inputs: int, n_outputs: int, encoded_points: int = 1
) -> int:
    """Trainable parameters of a hash grid (one level per octave) plus its MLP, which sees `n_inputs`
    other features and the grid's features of `encoded_points` points."""
    levels, grid = octaves + size.extra_levels, size.grid
    rows = sum(min(2**grid.log2_table_size, (coarsest * 2**level + 1) ** 3) for level in range(levels))
    n_in = n_inputs + encoded_points * levels * grid.features_per_level
    layers = [n_in] + [size.mlp.width] * size.mlp.depth + [n_outputs]
    mlp = sum((a + 1) * b for a, b in itertools.pairwise(layers))
    return rows * grid.features_per_level + mlp


def octaves(resolutions: list[int]) -> int:
    """Hash-grid levels: one per octave from the coarsest built LoD to the finest."""
    return int(math.log2(resolutions[0] // resolutions[-1])) + 1


def plan(scene: SceneRef, config: LodConfig) -> Plan:
    asset = choose_asset(scene, config)
    extent = cube_extent(asset.bounds, config.finest_resolution)
    levels = choose_resolutions(scene.spec, config, extent)
    resolutions = [r for r, _ in levels]
    n_oct = octaves(resolutions)
    sh = (config.sh_degree + 1) ** 2
    appearance = parameter_count(config.appearance, n_oct, resolutions[-1], 2 * sh, 3)
    visibility = parameter_count(config.visibility, n_oct, resolutions[-1], 0, 1, encoded_points=2)
    items = [
        PlanItem(name=c.name, choice="prefilter" if c.prefiltered else "keep", reason=c.reason)
        for c in asset.choices
    ]
    items += [
        PlanItem(name=f"LoD {i}", choice=f"{r}^3 voxels ({extent / r:.4g} per voxel)", reason=why)
        for i, (r, why) in enumerate(levels)
    ]
    items.append(
        PlanItem(
            name="networks",
            choice=f"appearance {appearance:,} + visibility {visibility:,} parameters "
            f"({2 * (appearance + visibility) / 1e6:.2f} MB in float16)",
            reason=f"hash grids of {n_oct} levels from {resolutions[-1]}^3; appearance: "
            f"{config.appearance.grid.describe()}, {config.appearance.mlp.describe()}; visibility: "
            f"{config.visibility.grid.describe()}, {config.visibility.mlp.describe()}; sparsity per level "
            "is measured when the job voxelises and reported with the artifact",
        )
    )
    seconds = config.train.steps * config.batch_size / TRAINING_SAMPLES_PER_SECOND
    voxel_bound = sum(min(r**3, 8 * asset.triangles) for r in resolutions)  # occupied <= all, <= ~8 per tri
    seconds += voxel_bound * config.threshold_samples / THRESHOLD_SAMPLES_PER_SECOND
    camera, height = scene.spec.camera, config.evaluation_max_height  # each LoD's image is at most this high
    pixels = height * round(height * camera.width / camera.height)
    # every LoD is rendered with and without light sampling and timed, against a reference of its size
    lods = Evaluation(
        pixels, len(levels) * (3 * config.evaluation_spp + config.reference_spp), 8, 4 * len(levels)
    )
    fixed = fixed_costs(
        scene, config, (report_view(pixels, config.evaluation_spp, config.reference_spp), lods)
    )
    items.append(fixed.item())
    seconds += fixed.seconds
    summary = (
        f"{len(asset.names)} object(s), {asset.triangles:,} triangles, "
        f"{asset.mesh_bytes / 1e6:.2f} MB of mesh; {len(levels)} LoD(s) "
        f"{', '.join(f'{r}^3' for r in resolutions)}"
    )
    return Plan(items=items, estimated_seconds=seconds, summary=summary)
