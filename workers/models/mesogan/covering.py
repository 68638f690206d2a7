"""A scene's surfaces covered by the material: the shell over them, the generated plane laid over their
UVs (a box projection where a mesh has none, `atlas`), and, for comparison, the same surfaces covered by
real strand geometry.

The plane spans the UV square; its size in slab heights is the surfaces' world size per UV unit
(sqrt(world area / UV area)) over the shell height, so a texel has the size it had in training. The shell
height is given in world units or relative to the covered surfaces' size (`ShellHeight`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from workers.models.mesogan.aggregate import NeuralMaterial, ShellAggregate
from workers.models.mesogan.atlas import laid_out, uv_areas
from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SKIN, cone_radius, normalized_structure
from workers.models.mesogan.shell import Shell
from workers.models.mesogan.slab import Window, draw_noise, generate_planes
from workers.models.mesogan.volume import mip_stack
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Appearance, Camera, Diffuse, ShellHeight, Structure
from workers.scene.generators.mesoscale import grow_on_triangles
from workers.scene.geometry.compile import CompiledScene, ObjectGeometry
from workers.scene.geometry.mesh import MeshData

MAX_PLANE = 4096  # texels per side of a generated plane


@dataclass(frozen=True)
class Covering:
    triangles: np.ndarray  # indices into the compiled scene
    uvs: np.ndarray  # (T, 3, 2) the triangles' UVs, or their box projection (`atlas.laid_out`)
    plane_units: float  # slab heights per UV unit
    resolution: int  # texels per side of the plane over the UV square


def covered_triangles(
    scene: CompiledScene, surfaces: list[str], field: str = "config.surfaces"
) -> np.ndarray:
    """The triangles whose material is one of `surfaces`; `SceneError` naming `field` if none match."""
    names = [n for n in surfaces if n in scene.material_names]
    if not names:
        raise SceneError(
            field,
            f"no scene material is named {surfaces}; the scene's materials are {scene.material_names}",
        )
    ids = [scene.material_names.index(n) for n in names]
    return np.flatnonzero(np.isin(scene.material_ids, ids))


def covering(
    scene: CompiledScene,
    surfaces: list[str],
    shell_height: float,
    texel: float,
    field: str = "config.surfaces",
) -> Covering:
    """The covered triangles and the plane they imply; `SceneError` naming `field` if none match."""
    triangles = covered_triangles(scene, surfaces, field)
    uvs = laid_out(scene.uvs[triangles], scene.positions[triangles], scene.object_ids[triangles])
    uv_area = uv_areas(uvs).sum()
    if uv_area <= 0:
        raise SceneError(field, f"the surfaces {surfaces} cover no area")
    plane_units = math.sqrt(scene.areas[triangles].sum() / uv_area) / shell_height
    resolution = int(min(MAX_PLANE, max(8, math.ceil(plane_units / texel))))
    return Covering(triangles, uvs, plane_units, resolution)


def world_shell_height(
    scene: CompiledScene, triangles: np.ndarray, height: ShellHeight, default: float
) -> float:
    """`height` in world units over `triangles` (`ShellHeight`), the artifact's `default` if unset."""
    corners = scene.positions[triangles].reshape(-1, 3).astype(np.float64)
    return height.world_height(float(np.linalg.norm(np.ptp(corners, 0))), default)


def build_shell(
    scene: CompiledScene, cover: Covering, height: float, field: str = "config.shell_height"
) -> Shell:
    t = cover.triangles
    return Shell(scene.positions[t], scene.shading_normals[t], cover.uvs, height, field=field)


def neural_material(
    model: MesoGAN,
    config: MesoganConfig,
    cover: Covering,
    structure: Structure,
    appearance: Appearance,
    seed: int,
) -> NeuralMaterial:
    """The plane of the instance `seed` with these parameters over the covering's UV square, with the mip
    levels training rendered with: the shell reads no footprint wider than training's
    (`sampling.widest_footprint`), so deeper levels would never be read."""
    window = Window((0, 0), (cover.resolution, cover.resolution), cover.plane_units / cover.resolution)
    device = next(model.parameters()).device
    generator = torch.Generator().manual_seed(seed)
    latent = torch.randn(1, config.latent_dims, generator=generator).to(device)
    s = torch.tensor(normalized_structure(structure), dtype=torch.float32, device=device)[None]
    with torch.no_grad():
        planes = generate_planes(model, config, s, latent, draw_noise(model, config, 1, seed), window)
    a = torch.tensor(appearance.color(), dtype=torch.float32, device=device)
    return NeuralMaterial(model, config, mip_stack(planes, config.mip_levels), window, a)


def shell_aggregate(
    scene: CompiledScene,
    surfaces: list[str],
    model: MesoGAN,
    config: MesoganConfig,
    structure: Structure,
    appearance: Appearance,
    seed: int,
    height: ShellHeight,
    view: Camera,
    fields: tuple[str, str],
) -> ShellAggregate:
    """The material of the instance `seed` on a shell of `height` (the artifact's if unset) over the
    scene's `surfaces` (by material name), as the path tracer's aggregate for paths starting at the camera
    `view`: what the kind's `:render` and a scene's mesogan material (`material`) draw. SceneErrors name
    `fields`: the surfaces', and the prefix of the shell height's (`params.`)."""
    triangles = covered_triangles(scene, surfaces, fields[0])
    world = world_shell_height(scene, triangles, height, config.shell_height)
    cover = covering(scene, surfaces, world, config.texel, field=fields[0])
    shell = build_shell(scene, cover, world, field=fields[1] + height.height_field())
    material = neural_material(model, config, cover, structure, appearance, seed)
    return ShellAggregate(shell, material, config.samples_per_ray, cone_radius(view.fov, view.height))


def with_strands(
    scene: CompiledScene,
    cover: Covering,
    config: MesoganConfig,
    structure: Structure,
    appearance: Appearance,
    seed: int,
) -> CompiledScene:
    """`scene` with real strands grown on the covered triangles, which take the training slabs' skin: the
    geometry the shell stands in for, base included."""
    t = cover.triangles
    strands = grow_on_triangles(
        scene.positions[t].astype(np.float64),
        scene.shading_normals[t].astype(np.float64),
        config.material,
        structure,
        config.shell_height,
        seed,
    )
    skinned = with_material(scene, t, "mesogan.skin", Diffuse(reflectance=SKIN))
    return with_mesh(skinned, strands, "mesogan.strands", Diffuse(reflectance=appearance.color()))


def with_material(scene: CompiledScene, triangles: np.ndarray, material: str, definition) -> CompiledScene:
    """`scene` with `triangles` shaded by the new material `definition`."""
    spec = scene.spec.model_copy(update={"materials": {**scene.spec.materials, material: definition}})
    material_ids = scene.material_ids.copy()
    material_ids[triangles] = len(scene.material_names)
    return replace(
        scene, spec=spec, material_ids=material_ids, material_names=[*scene.material_names, material]
    )


def with_mesh(scene: CompiledScene, mesh: MeshData, material: str, definition) -> CompiledScene:
    """`scene` with one more object: `mesh` in world space, shaded by the new material `definition`."""
    positions = mesh.vertices[mesh.faces]
    normals = mesh.normals[mesh.faces]
    cross = np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0])
    length = np.maximum(np.linalg.norm(cross, axis=1), 1e-300)
    n, start = len(positions), scene.num_triangles
    material_id, object_id = len(scene.material_names), len(scene.objects)
    instance = int(scene.instance_ids.max()) + 1
    spec = scene.spec.model_copy(update={"materials": {**scene.spec.materials, material: definition}})
    geometry = ObjectGeometry(material, object_id, mesh, [np.eye(4)], [(start, start + n)], material)
    return replace(
        scene,
        spec=spec,
        positions=np.concatenate([scene.positions, positions.astype(np.float32)]),
        shading_normals=np.concatenate([scene.shading_normals, normals.astype(np.float32)]),
        uvs=np.concatenate([scene.uvs, mesh.uvs[mesh.faces].astype(np.float32)]),
        geometric_normals=np.concatenate(
            [scene.geometric_normals, (cross / length[:, None]).astype(np.float32)]
        ),
        areas=np.concatenate([scene.areas, 0.5 * length]),
        material_ids=np.concatenate([scene.material_ids, np.full(n, material_id, np.int32)]),
        object_ids=np.concatenate([scene.object_ids, np.full(n, object_id, np.int32)]),
        instance_ids=np.concatenate([scene.instance_ids, np.full(n, instance, np.int32)]),
        emission=np.concatenate([scene.emission, np.zeros((n, 3), np.float32)]),
        two_sided_emission=np.concatenate([scene.two_sided_emission, np.zeros(n, bool)]),
        material_names=[*scene.material_names, material],
        objects=[*scene.objects, geometry],
        tangents=_extended(scene.tangents, n, 0.0),
        vertex_colors=_extended(scene.vertex_colors, n, 1.0),
    )


def _extended(corners: np.ndarray | None, n: int, value: float) -> np.ndarray | None:
    """Per-corner attributes of a scene for `n` more triangles that do not use them."""
    if corners is None:
        return None
    return np.concatenate([corners, np.full((n, *corners.shape[1:]), value, corners.dtype)])
