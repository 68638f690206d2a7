"""USD import (usd-core): a textured scene written as glTF and as USD renders to the same image; instancing,
point instancers, Z-up stages, lights, USDZ packages and references leaving the folder."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from PIL import Image

pytest.importorskip("pxr")
from pxr import Sdf, UsdGeom, UsdLux, UsdUtils, Vt

from tests.support import usd_files as usd
from tests.support.gltf_files import QUAD_INDICES, QUAD_NORMALS, QUAD_POSITIONS, QUAD_UVS, GltfBuilder
from workers.render.render import RenderSettings, render
from workers.scene.format.errors import SceneError
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import load_scene

FOV = 43.0


def translate_rotate_x(t, degrees: float = 0.0, scale: float = 1.0) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    m = np.eye(4)
    m[:3, :3] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) * scale
    m[:3, 3] = t
    return m


def scene_parts():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    ball_normals = ball.vertices / np.linalg.norm(ball.vertices, axis=1, keepdims=True)
    quad = (QUAD_POSITIONS, QUAD_INDICES, QUAD_NORMALS, QUAD_UVS)
    sphere = (ball.vertices.astype(np.float32), ball.faces, ball_normals, None)
    objects = [
        ("floor", quad, translate_rotate_x((0, 0, 0), -90, 3.0), "Floor"),
        ("gold", sphere, translate_rotate_x((-1.1, 0.5, 0.0)), "Gold"),
        ("blend", sphere, translate_rotate_x((1.1, 0.5, 0.0)), "Blend"),
        ("lamp", quad, translate_rotate_x((0.0, 2.5, 0.5), 90, 0.6), "Lamp"),
    ]
    materials = {
        "Floor": dict(texture=True, metallic=0.0, roughness=0.7),
        "Gold": dict(base=(1.0, 0.77, 0.34), metallic=1.0, roughness=0.4),
        "Blend": dict(base=(0.2, 0.6, 0.3), metallic=0.5, roughness=0.5),
        "Lamp": dict(base=(1.0, 1.0, 1.0), metallic=0.0, roughness=1.0, emission=6.0),
    }
    return objects, materials, translate_rotate_x((0.0, 1.6, 4.5), -19.6)


def checker_png(folder):
    checker = np.zeros((8, 8, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = (230, 200, 120)
    checker[1::2, ::2] = checker[::2, 1::2] = (40, 90, 160)
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(checker).save(folder / "checker.png")
    return checker


def write_gltf(folder):
    objects, materials, camera = scene_parts()
    builder = GltfBuilder()
    index = {}
    for name, m in materials.items():
        pbr = {"metallicFactor": m["metallic"], "roughnessFactor": m["roughness"]}
        if m.get("texture"):
            pbr["baseColorTexture"] = {
                "index": builder.texture(builder.image(checker_png(folder), uri="checker.png"))
            }
        else:
            pbr["baseColorFactor"] = [*m["base"], 1.0]
        fields = {"emissiveFactor": [1.0, 1.0, 1.0]} if "emission" in m else {}
        if "emission" in m:
            builder.use("KHR_materials_emissive_strength")
            fields["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": m["emission"]}}
        index[name] = builder.material(name=name, pbrMetallicRoughness=pbr, **fields)
    for name, (positions, triangles, normals, uvs), matrix, material in objects:
        mesh = builder.mesh(
            positions, triangles, normals=normals, uvs=uvs, material=index[material], name=name
        )
        builder.node(mesh=mesh, matrix=matrix.T.ravel().tolist())
    light = builder.light(type="point", intensity=3.0)
    builder.node(extensions={"KHR_lights_punctual": {"light": light}}, translation=[2.0, 2.0, 2.0])
    builder.node(camera=builder.camera(yfov=math.radians(FOV), aspect=1.0), matrix=camera.T.ravel().tolist())
    return builder.save(folder / "scene.gltf")


def write_usd(folder, suffix=".usda"):
    objects, materials, camera = scene_parts()
    checker_png(folder)
    stage = usd.new_stage(folder / f"scene{suffix}")
    bound = {}
    for name, m in materials.items():
        inputs = {"metallic": m["metallic"], "roughness": m["roughness"]}
        if "base" in m:
            inputs["diffuseColor"] = m["base"]
        if "emission" in m:
            inputs["emissiveColor"] = (m["emission"],) * 3
        bound[name] = usd.preview_surface(
            stage, f"/World/Looks/{name}", texture="./checker.png" if m.get("texture") else None, **inputs
        )
    for name, (positions, triangles, normals, uvs), matrix, material in objects:
        usd.mesh(stage, f"/World/{name}", positions, triangles, normals=normals, uvs=uvs, matrix=matrix,
                 material=bound[material])  # fmt: skip
    usd.point_light(stage, "/World/Point", (2.0, 2.0, 2.0), 3.0)
    usd.camera(stage, "/World/Camera", camera, FOV)
    stage.GetRootLayer().Save()
    return folder / f"scene{suffix}"


def rendered(path):
    scene, folder = load_scene(path)
    return scene, render(
        compile_scene(scene, folder), RenderSettings(width=48, height=48, spp=4, seed=5)
    ).image


def test_the_same_textured_scene_as_gltf_and_as_usd_renders_the_same_image(tmp_path):
    gltf_scene, gltf_image = rendered(write_gltf(tmp_path / "gltf"))
    usd_scene, usd_image = rendered(write_usd(tmp_path / "usd"))
    assert sorted(m.type for m in usd_scene.materials.values()) == ["pbr"] * 4
    assert {m.diffuse for m in usd_scene.materials.values()} == {"energy_conserving"}
    assert usd_scene.materials["Floor"].base_color_texture.path == "checker.png"
    assert usd_scene.lights == gltf_scene.lights and not usd_scene.notes
    assert usd_scene.camera.fov == pytest.approx(FOV, rel=1e-5)
    assert gltf_image.mean() > 0.01
    # the same paths: only float32 rounding of the inputs (USD's colours, st = 1 - v) differs
    assert np.abs(usd_image - gltf_image).max() < 1e-4


def test_a_usdz_package_carries_its_texture(tmp_path):
    path = write_usd(tmp_path / "src", ".usdc")
    package = tmp_path / "scene.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(path)), str(package))
    scene, folder = load_scene(package)
    texture = scene.materials["Floor"].base_color_texture
    assert (texture.path, texture.member) == ("scene.usdz", "checker.png")
    surf = compile_scene(scene, folder)
    from workers.render.materials import MaterialTable

    table = MaterialTable(surf)
    floor = surf.material_names.index("Floor")
    assert table.surfaces(np.array([floor]), np.array([[0.5 / 8, 0.5 / 8]])).base[0][0] > 0.7  # a light texel


def test_instances_point_instancers_and_z_up(tmp_path):
    stage = usd.new_stage(tmp_path / "inst.usda", up="Z")
    proto = stage.DefinePrim("/Protos/Tile")
    usd.mesh(stage, "/Protos/Tile/Quad", QUAD_POSITIONS, QUAD_INDICES)
    stage.GetPrimAtPath("/Protos").SetSpecifier(Sdf.SpecifierClass)  # not rendered where it sits
    for k in range(2):
        ref = stage.DefinePrim(f"/World/Tile{k}", "Xform")
        ref.GetReferences().AddInternalReference("/Protos/Tile")
        ref.SetInstanceable(True)
        usd.place(ref, translate_rotate_x((3.0 * k, 0.0, 0.0)))
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    usd.mesh(stage, "/World/Scatter/Protos/Quad", QUAD_POSITIONS, QUAD_INDICES)
    instancer.CreatePrototypesRel().SetTargets(["/World/Scatter/Protos"])
    instancer.CreateProtoIndicesAttr(Vt.IntArray([0, 0, 0]))
    instancer.CreatePositionsAttr(Vt.Vec3fArray([(0, 5, 0), (0, 5, 3), (0, 5, 6)]))
    UsdLux.DistantLight.Define(stage, "/World/Sun")  # shines along its -z: down, in a Z-up stage
    stage.GetRootLayer().Save()
    assert proto
    scene, folder = load_scene(tmp_path / "inst.usda")
    assert "axes: the stage is Z-up; turned Y-up" in scene.notes
    counts = sorted(len(o.instances or [None]) for o in scene.objects)
    assert counts == [2, 3]  # one mesh per prototype, placed per instance
    compiled = compile_scene(scene, folder)
    assert compiled.num_triangles == 10
    np.testing.assert_allclose(scene.lights[0].direction, (0, -1, 0), atol=1e-12)
    # Z-up: the instancer's +y offset 5 stays horizontal (our -z), its z offsets go up (our +y)
    centres = compiled.positions.reshape(-1, 6, 3).mean(axis=1)  # two triangles per quad
    expected = {(0, 0, 0), (3, 0, 0), (0, 0, -5), (0, 3, -5), (0, 6, -5)}
    assert {tuple(c) for c in np.round(centres, 5) + 0.0} == expected


def test_references_outside_the_folder_and_bad_meshes_are_errors(tmp_path):
    outside = usd.new_stage(tmp_path / "shared.usda")
    usd.mesh(outside, "/World/Quad", QUAD_POSITIONS, QUAD_INDICES)
    outside.SetDefaultPrim(outside.GetPrimAtPath("/World"))
    outside.GetRootLayer().Save()
    stage = usd.new_stage(tmp_path / "upload" / "scene.usda")
    stage.DefinePrim("/World/Ref").GetReferences().AddReference("../shared.usda")
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match="outside the folder") as caught:
        load_scene(tmp_path / "upload" / "scene.usda")
    assert "shared.usda" in caught.value.field
    stage = usd.new_stage(tmp_path / "upload" / "other.usda")  # as in an upload: the file is not there
    stage.DefinePrim("/World/Ref").GetReferences().AddReference("../gone.usda")
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match="Could not open asset") as caught:
        load_scene(tmp_path / "upload" / "other.usda")
    assert caught.value.field == "other.usda: /World/Ref"

    stage = usd.new_stage(tmp_path / "lines.usda")
    m = UsdGeom.Mesh.Define(stage, "/World/Broken")
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(QUAD_POSITIONS))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([2, 2]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match="fewer than 3") as caught:
        load_scene(tmp_path / "lines.usda")
    assert "/World/Broken" in caught.value.field


def test_a_scene_file_imports_a_usd_file_and_overrides_its_camera(tmp_path):
    write_usd(tmp_path / "assets")
    (tmp_path / "scene.yaml").write_text(
        "import: assets/scene.usda\ncamera: {position: [0, 2, 9], target: [0, 0, 0]}\n"
        "environment: {type: constant, radiance: [0.1, 0.1, 0.1]}\n"
    )
    scene, folder = load_scene(tmp_path / "scene.yaml")
    assert scene.camera.position == (0.0, 2.0, 9.0) and scene.environment.type == "constant"
    assert scene.objects[0].shape.path == "assets/scene.usda"
    assert scene.materials["Floor"].base_color_texture.path == "assets/checker.png"
    assert compile_scene(scene, folder).num_triangles > 0


@pytest.mark.parametrize("kind_name", ["lod", "lsnif"])
def test_model_kinds_plan_on_imported_scenes(tmp_path, kind_name):
    """What `nbake submit model.glb --kind lod` plans on: the imported objects, the same from either file."""
    from workers.models.registry import get_kind
    from workers.scene.portability.reference import SceneRef

    kind = get_kind(kind_name)
    summaries = []
    for path in (write_gltf(tmp_path / "gltf"), write_usd(tmp_path / "usd")):
        scene, folder = load_scene(path)
        summaries.append(kind.plan(SceneRef(scene, folder), kind.resolve_config("quick", {})).summary)
    assert summaries[0] == summaries[1], summaries
