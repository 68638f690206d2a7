"""Export a compiled SceneSpec to a Mitsuba 3 scene dictionary (scalar_rgb), for comparisons.

Geometry goes through PLY files of the compiled world-space triangles, so both renderers see
exactly the same triangles, shading normals and UVs (textures map to Mitsuba's `checkerboard` and
`bitmap`). Opaque materials are wrapped in `twosided`,
matching our renderer's two-sided convention. The film uses a box filter so that a pixel is the
plain average of its samples, as in our renderer.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from tests.support.mitsuba_load import MATRIX
from workers.scene.format import spec
from workers.scene.geometry.compile import CompiledScene


def _rgb(value) -> dict:
    return {"type": "rgb", "value": [float(x) for x in value]}


def _reflectance(value: spec.ColorOrTexture, base_dir: Path | None = None) -> dict:
    """A colour, or a texture looked up with the same UV convention (workers/scene/importers/textures.py)."""
    match value:
        case spec.CheckerTexture():
            # Mitsuba's checkerboard has 2 x 2 cells per unit of UV, ours `scale` x `scale`.
            return {
                "type": "checkerboard",
                "color0": _rgb(value.color0),
                "color1": _rgb(value.color1),
                "to_uv": _scalar_transform(np.diag([value.scale / 2, value.scale / 2, 1.0, 1.0])),
            }
        case spec.ImageTexture():
            if value.image is not None or value.wrap_u != value.wrap_v:
                raise TypeError("no Mitsuba export for images inside glTF files or with two wrap modes")
            path = Path(value.path)
            return {
                "type": "bitmap",
                "filename": str(path if path.is_absolute() or base_dir is None else base_dir / path),
                "filter_type": "bilinear",
                "wrap_mode": value.wrap_u,
                "raw": value.color_space == "linear",
            }
        case _:
            return _rgb(value)


def _scalar_transform(matrix: np.ndarray):
    import mitsuba as mi

    return mi.ScalarTransform4f(np.asarray(matrix, dtype=float).tolist())


def mitsuba_bsdf(material: spec.Material, base_dir: Path | None = None) -> dict:
    match material:
        case spec.Diffuse():
            inner = {"type": "diffuse", "reflectance": _reflectance(material.reflectance, base_dir)}
        case spec.Conductor() if material.roughness == 0:
            inner = {"type": "conductor", "material": "none", "specular_reflectance": _rgb(material.specular)}
        case spec.Conductor():
            inner = {
                "type": "roughconductor",
                "material": "none",
                "distribution": "ggx",
                "alpha": float(material.roughness),
                "specular_reflectance": _rgb(material.specular),
            }
        case spec.Plastic() if material.roughness == 0:
            inner = {
                "type": "plastic",
                "int_ior": float(material.ior),
                "ext_ior": 1.0,
                "diffuse_reflectance": _reflectance(material.diffuse, base_dir),
            }
        case spec.Plastic():
            inner = {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": float(material.roughness),
                "int_ior": float(material.ior),
                "ext_ior": 1.0,
                "diffuse_reflectance": _reflectance(material.diffuse, base_dir),
            }
        case spec.Dielectric() if material.roughness == 0:
            return {"type": "dielectric", "int_ior": float(material.ior), "ext_ior": 1.0}
        case spec.Dielectric():
            return {
                "type": "roughdielectric",
                "distribution": "ggx",
                "alpha": float(material.roughness),
                "int_ior": float(material.ior),
                "ext_ior": 1.0,
            }
        case spec.PbrMaterial():
            return mitsuba_principled(material, base_dir)
        case _:
            raise TypeError(f"no Mitsuba export for {type(material).__name__}")
    return {"type": "twosided", "bsdf": inner}


def mitsuba_principled(material: spec.PbrMaterial, base_dir: Path | None = None) -> dict:
    """`principled` with the parameters our `pbr` family has (workers/render/bsdfs/pbr.py); opaque ones
    (no transmission lobe) wrapped in `twosided`, as ours are. A base colour texture must have factor 1,
    and a diffuse lobe must be Burley's (`diffuse: burley`): metals and glass have none."""
    unsupported = [
        name
        for name in (
            "metallic_roughness_texture",
            "transmission_texture",
            "normal_texture",
            "emission_texture",
        )
        if getattr(material, name) is not None
    ]
    if unsupported or (material.base_color_texture is not None and material.base_color != (1.0, 1.0, 1.0)):
        raise TypeError(f"no Mitsuba export for a pbr material with {unsupported or 'a scaled texture'}")
    if material.diffuse != "burley" and material.metallic < 1 and material.transmission < 1:
        raise TypeError("no Mitsuba export for an energy-conserving diffuse lobe (principled's is Burley's)")
    base = material.base_color_texture if material.base_color_texture is not None else material.base_color
    principled = {
        "type": "principled",
        "base_color": _reflectance(base, base_dir),
        "metallic": float(material.metallic),
        "roughness": float(material.roughness),
        "eta": float(material.ior),
        "spec_trans": float(material.transmission),
    }
    if material.transmission == 0 or material.metallic == 1:
        return {"type": "twosided", "bsdf": principled}
    return principled


def mitsuba_scene_dict(
    scene: CompiledScene, workdir: Path, spp: int, max_depth: int, width=None, height=None
):
    """A dict for `mitsuba.load_dict`; writes one PLY per object instance into `workdir`."""
    import mitsuba as mi

    workdir.mkdir(parents=True, exist_ok=True)
    cam = scene.spec.camera
    out: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": 5},
        "sensor": {
            "type": "perspective",
            "fov": float(cam.fov),
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(cam.position), target=list(cam.target), up=list(cam.up)
            ),
            "film": {
                "type": "hdrfilm",
                "width": width or cam.width,
                "height": height or cam.height,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
                "component_format": "float32",
            },
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    for obj in scene.objects:
        source = scene.spec.objects[obj.index]
        for k, (lo, hi) in enumerate(obj.triangle_ranges):
            tris = scene.positions[lo:hi].reshape(-1, 3)
            normals = scene.shading_normals[lo:hi].reshape(-1, 3)
            uv = trimesh.visual.TextureVisuals(uv=scene.uvs[lo:hi].reshape(-1, 2))
            faces = np.arange(len(tris)).reshape(-1, 3)
            path = workdir / f"{obj.name}_{k}.ply"
            trimesh.Trimesh(tris, faces, vertex_normals=normals, visual=uv, process=False).export(path)
            entry = {
                "type": "ply",
                "filename": str(path),
                "bsdf": mitsuba_bsdf(scene.spec.materials[obj.material], scene.base_dir),
            }
            if source.emission is not None:
                if source.two_sided_emission:
                    raise ValueError("Mitsuba area emitters are one-sided")
                entry["emitter"] = {"type": "area", "radiance": _rgb(source.emission)}
            out[f"{obj.name}_{k}"] = entry
    for i, light in enumerate(scene.spec.lights):
        if isinstance(light, spec.PointLight):
            out[f"light_{i}"] = {
                "type": "point",
                "position": list(light.position),
                "intensity": _rgb(light.intensity),
            }
        elif isinstance(light, spec.SpotLight):
            raise TypeError("no Mitsuba export for spot lights (Mitsuba's falloff is not glTF's)")
        else:
            out[f"light_{i}"] = {
                "type": "directional",
                "direction": list(light.direction),
                "irradiance": _rgb(light.irradiance),
            }
    env = scene.spec.environment
    if isinstance(env, spec.ConstantBackground):
        out["environment"] = {"type": "constant", "radiance": _rgb(env.radiance)}
    elif scene.environment_image is not None:
        matrix = np.eye(4)
        matrix[:3, :3] = scene.environment_rotation
        out["environment"] = {
            "type": "envmap",
            "bitmap": mi.Bitmap(np.ascontiguousarray(scene.environment_image, dtype=np.float32)),
            "to_world": mi.ScalarTransform4f(matrix.tolist()),
        }
    return out


def render_mitsuba(
    scene: CompiledScene, workdir: Path, spp: int, max_depth: int, seed: int, width=None, height=None
):
    """A Mitsuba `scalar_rgb` render as an (H, W, 3) float64 array."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    loaded = mi.load_dict(mitsuba_scene_dict(scene, workdir, spp, max_depth, width, height))
    return np.array(mi.render(loaded, spp=spp, seed=seed), dtype=np.float64)[..., :3]


def mitsuba_scene_file(
    scene: CompiledScene, workdir: Path, spp: int, max_depth: int, width=None, height=None
) -> Path:
    """`mitsuba_scene_dict` as a JSON file beside its PLY files (the environment map as an EXR), for
    `tests.support.mitsuba_load` to load in a process that imports nothing of ours."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")

    def plain(node):
        if isinstance(node, mi.ScalarTransform4f):
            return {MATRIX: np.array(node.matrix).tolist()}
        if isinstance(node, dict) and isinstance(node.get("bitmap"), mi.Bitmap):
            path = workdir / "environment.exr"
            node["bitmap"].write(str(path))
            return {**plain({k: v for k, v in node.items() if k != "bitmap"}), "filename": str(path)}
        if isinstance(node, dict):
            return {key: plain(value) for key, value in node.items()}
        return node

    path = workdir / "scene.json"
    path.write_text(json.dumps(plain(mitsuba_scene_dict(scene, workdir, spp, max_depth, width, height))))
    return path
