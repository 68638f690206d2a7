"""glTF 2.0 import: hierarchy, instancing, materials, textures, lights, cameras, defaults and bad input, on
files written here with pygltflib (tests/support/gltf_files.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.support.gltf_files import QUAD_POSITIONS, GltfBuilder, quad
from workers.render.integrator import PathTracer
from workers.render.materials import MaterialTable
from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import srgb_to_linear
from workers.scene.portability.io import load_scene

S = math.sqrt(0.5)


def rotation_z90_quaternion():
    return [0.0, 0.0, S, S]  # (x, y, z, w): 90 degrees about +z


def hierarchy(builder: GltfBuilder) -> list[np.ndarray]:
    """A quad mesh used by three nodes: a child under a rotated, scaled parent, a root with a matrix, and
    the parent's other child; returns the three node-to-world matrices in node order."""
    mesh = quad(builder, builder.material(name="Red", pbrMetallicRoughness={"baseColorFactor": [1, 0, 0, 1]}))
    child_a = builder.node(mesh=mesh, translation=[1.0, 0.0, 0.0], root=False)
    child_b = builder.node(mesh=mesh, translation=[0.0, 0.0, 2.0], root=False)
    builder.node(
        children=[child_a, child_b],
        translation=[0.0, 5.0, 0.0],
        rotation=rotation_z90_quaternion(),
        scale=[2, 2, 2],
    )
    matrix = np.eye(4)
    matrix[:3, 3] = [-4.0, 0.0, 1.0]
    builder.node(mesh=mesh, matrix=matrix.T.ravel().tolist())  # glTF stores matrices column-major
    parent = np.eye(4)
    parent[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]) * 2
    parent[:3, 3] = [0, 5, 0]
    a, b = np.eye(4), np.eye(4)
    a[:3, 3], b[:3, 3] = [1, 0, 0], [0, 0, 2]
    return [parent @ a, parent @ b, matrix]


def world_corners(matrix: np.ndarray) -> np.ndarray:
    return (np.c_[QUAD_POSITIONS, np.ones(4)] @ matrix.T)[:, :3]


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_node_hierarchy_places_one_mesh_once_per_node(tmp_path, suffix):
    builder = GltfBuilder()
    matrices = hierarchy(builder)
    scene, folder = load_scene(builder.save(tmp_path / f"model{suffix}"))
    assert len(scene.objects) == 1 and len(scene.objects[0].instances) == 3  # instancing, not copies
    compiled = compile_scene(scene, folder)
    assert compiled.num_triangles == 6
    for k, matrix in enumerate(matrices):
        got = np.unique(compiled.positions[2 * k : 2 * k + 2].reshape(-1, 3).round(5), axis=0)
        want = np.unique(world_corners(matrix).round(5), axis=0)
        np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(compiled.geometric_normals[:2], [[0, 0, 1]] * 2, atol=1e-6)


def test_gltf_and_glb_of_one_scene_compile_to_the_same_triangles_and_materials(tmp_path):
    arrays = []
    for suffix in (".gltf", ".glb"):
        builder = GltfBuilder()
        hierarchy(builder)
        scene, folder = load_scene(builder.save(tmp_path / suffix[1:] / f"model{suffix}"))
        compiled = compile_scene(scene, folder)
        arrays.append((compiled.positions, compiled.uvs, compiled.shading_normals, scene.materials))
    for a, b in zip(*arrays, strict=True):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b


def textured_material(builder: GltfBuilder, external: bool) -> int:
    checker = np.zeros((4, 4, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = 255
    base = builder.texture(
        builder.image(checker, uri="tex/base color.png" if external else None), 33071, 33648
    )
    mr = builder.texture(builder.image(np.full((2, 2, 3), (0, 128, 64), np.uint8)))
    builder.use("KHR_materials_ior")
    builder.use("KHR_materials_transmission")
    builder.use("KHR_materials_emissive_strength")
    return builder.material(
        name="Glassy",
        pbrMetallicRoughness={
            "baseColorFactor": [0.5, 0.6, 0.7, 1.0],
            "baseColorTexture": {"index": base},
            "metallicFactor": 0.25,
            "roughnessFactor": 0.8,
            "metallicRoughnessTexture": {"index": mr},
        },
        emissiveFactor=[1.0, 0.5, 0.25],
        extensions={
            "KHR_materials_ior": {"ior": 1.7},
            "KHR_materials_transmission": {"transmissionFactor": 0.4},
            "KHR_materials_emissive_strength": {"emissiveStrength": 3.0},
        },
        doubleSided=True,
    )


@pytest.mark.parametrize("external", [False, True], ids=["embedded", "external"])
def test_materials_map_factors_extensions_textures_and_samplers(tmp_path, external):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder, textured_material(builder, external)))
    scene, folder = load_scene(builder.save(tmp_path / "m.gltf"))
    material = scene.materials["Glassy"]
    assert material.type == "pbr" and material.diffuse == "energy_conserving"
    assert (material.metallic, material.roughness, material.ior, material.transmission) == (
        0.25,
        0.8,
        1.7,
        0.4,
    )
    assert material.base_color == (0.5, 0.6, 0.7)
    base = material.base_color_texture
    assert (base.color_space, base.wrap_u, base.wrap_v) == ("srgb", "clamp", "mirror")
    assert material.metallic_roughness_texture.color_space == "linear"
    assert (base.path, base.image) == (("tex/base color.png", None) if external else ("m.gltf", 0))
    obj = scene.objects[0]
    assert obj.emission == (3.0, 1.5, 0.75) and obj.two_sided_emission  # emissive strength, double-sided

    # Colour spaces: sRGB base colour texels decode, the linear metallic-roughness ones do not.
    table = MaterialTable(compile_scene(scene, folder))
    surf = table.surfaces(np.zeros(2, np.int64), np.array([[0.125, 0.125], [0.375, 0.125]]))
    np.testing.assert_allclose(surf.base[0], [0.5, 0.6, 0.7], rtol=1e-6)  # white texel times the factor
    np.testing.assert_allclose(surf.base[1], [0.0, 0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(surf.extra[:, 2], 0.8 * 128 / 255, rtol=1e-6)  # roughness: G, linear
    np.testing.assert_allclose(surf.extra[:, 0], 0.25 * 64 / 255, rtol=1e-6)  # metallic: B, linear
    assert not np.isclose(srgb_to_linear(np.array(128 / 255)), 128 / 255)  # the two decodings differ


def test_lights_and_camera_are_placed_by_their_nodes(tmp_path):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder))
    builder.node(
        camera=builder.camera(yfov=math.radians(30), aspect=2.0),
        translation=[0.0, 1.0, 6.0],
        rotation=[0.0, S, 0.0, S],  # 90 degrees about +y: looks along -x
    )
    point = builder.light(type="point", color=[1.0, 0.5, 0.5], intensity=4.0)
    sun = builder.light(type="directional", intensity=2.0)
    spot = builder.light(type="spot", intensity=10.0, spot={"innerConeAngle": 0.2, "outerConeAngle": 0.5})
    builder.node(extensions={"KHR_lights_punctual": {"light": point}}, translation=[1.0, 2.0, 3.0])
    builder.node(
        extensions={"KHR_lights_punctual": {"light": sun}}, rotation=[-S, 0.0, 0.0, S]
    )  # points down
    builder.node(extensions={"KHR_lights_punctual": {"light": spot}}, translation=[0.0, 4.0, 0.0])
    scene, _ = load_scene(builder.save(tmp_path / "lit.glb"))
    cam = scene.camera
    np.testing.assert_allclose(cam.position, (0, 1, 6), atol=1e-12)
    np.testing.assert_allclose(np.subtract(cam.target, cam.position), (-1, 0, 0), atol=1e-12)
    assert cam.fov == pytest.approx(30) and (cam.width, cam.height) == (512, 256)
    point_light, sun_light, spot_light = scene.lights
    assert point_light.position == (1.0, 2.0, 3.0) and point_light.intensity == (4.0, 2.0, 2.0)
    np.testing.assert_allclose(sun_light.direction, (0, -1, 0), atol=1e-12)
    assert sun_light.irradiance == (2.0, 2.0, 2.0)
    assert spot_light.type == "spot" and spot_light.outer_cone == pytest.approx(math.degrees(0.5))
    assert scene.environment is None and not scene.notes


def test_a_file_without_camera_or_light_gets_defaults_and_says_so(tmp_path):
    builder = GltfBuilder()
    hierarchy(builder)
    scene, folder = load_scene(builder.save(tmp_path / "bare.glb"))
    assert scene.environment == spec.EnvironmentMap(procedural="studio")
    assert any(n.startswith("camera:") for n in scene.notes)
    assert any(n.startswith("environment:") for n in scene.notes)
    compiled = compile_scene(scene, folder)
    # the framing camera sees every triangle
    from workers.render.camera import PinholeCamera

    camera = PinholeCamera(scene.camera)
    corners = compiled.positions.reshape(-1, 3).astype(np.float64)
    o, d = camera.rays(np.array([scene.camera.width / 2]), np.array([scene.camera.height / 2]))
    to_corners = corners - o
    cosines = to_corners @ d[0] / np.linalg.norm(to_corners, axis=1)
    assert cosines.min() > math.cos(math.radians(scene.camera.fov / 2) * 1.01)


def test_unsupported_optional_features_are_listed_as_ignored(tmp_path):
    builder = GltfBuilder()
    material = builder.material(name="Leaf", alphaMode="MASK", occlusionTexture={"index": 0})
    builder.texture(builder.image(np.zeros((2, 2, 3))))
    builder.node(mesh=quad(builder, material))
    builder.use("KHR_texture_transform")
    builder.use("KHR_materials_clearcoat")
    scene, _ = load_scene(builder.save(tmp_path / "ignored.glb"))
    ignored = [n for n in scene.notes if n.startswith("ignored:")]
    assert any("KHR_texture_transform" in n for n in ignored)
    assert any("KHR_materials_clearcoat" in n for n in ignored)
    assert any("alphaMode MASK" in n for n in ignored)
    assert any("occlusionTexture" in n for n in ignored)


def test_bad_files_are_errors_naming_what_is_wrong(tmp_path):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder))
    builder.use("KHR_draco_mesh_compression", required=True)
    with pytest.raises(SceneError, match="KHR_draco_mesh_compression") as caught:
        load_scene(builder.save(tmp_path / "draco.glb"))
    assert caught.value.field == "extensionsRequired"

    builder = GltfBuilder()
    builder.node(mesh=builder.mesh(QUAD_POSITIONS, [0, 1, 1, 2], mode=1), name="Wires")
    with pytest.raises(SceneError, match="LINES") as caught:
        load_scene(builder.save(tmp_path / "lines.glb"))
    assert "Wires" in caught.value.field

    builder = GltfBuilder()
    texture = builder.texture(builder.image(np.zeros((2, 2, 3)), uri="gone.png"))
    builder.node(
        mesh=quad(builder, builder.material(pbrMetallicRoughness={"baseColorTexture": {"index": texture}}))
    )
    path = builder.save(tmp_path / "missing" / "m.gltf")
    (path.parent / "gone.png").unlink()
    with pytest.raises(SceneError, match=r"gone\.png") as caught:
        load_scene(path)
    assert caught.value.field == "materials[0].baseColorTexture"

    builder = GltfBuilder()
    builder.node(mesh=quad(builder))
    path = builder.save(tmp_path / "escape" / "m.gltf")
    document = path.read_text().replace('"m.bin"', '"../secret.bin"')
    path.write_text(document)
    (tmp_path / "secret.bin").write_bytes((path.parent / "m.bin").read_bytes())
    with pytest.raises(SceneError, match="outside the glTF file's folder"):
        load_scene(path)


def test_strips_and_fans_become_triangles_with_their_winding(tmp_path):
    builder = GltfBuilder()
    strip = builder.mesh(QUAD_POSITIONS[[0, 1, 3, 2]], mode=5)
    fan = builder.mesh(QUAD_POSITIONS, mode=6)
    builder.node(mesh=strip)
    builder.node(mesh=fan, translation=[3.0, 0.0, 0.0])
    scene, folder = load_scene(builder.save(tmp_path / "strips.glb"))
    compiled = compile_scene(scene, folder)
    assert compiled.num_triangles == 4
    np.testing.assert_allclose(compiled.geometric_normals, [[0, 0, 1]] * 4, atol=1e-6)
    assert compiled.areas.sum() == pytest.approx(8.0)


def test_a_scene_file_imports_a_gltf_and_overrides_parts_of_it(tmp_path):
    builder = GltfBuilder()
    hierarchy(builder)
    builder.save(tmp_path / "assets" / "model.glb")
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(
        yaml.safe_dump(
            {
                "import": "assets/model.glb",
                "camera": {"position": [0, 0, 20], "target": [0, 0, 0]},
                "materials": {"Red": {"type": "diffuse", "reflectance": [0.2, 0.3, 0.4]}},
                "objects": [
                    {
                        "name": "sun disk",
                        "shape": {"type": "sphere"},
                        "material": "Red",
                        "emission": [1, 1, 1],
                    }
                ],
            }
        )
    )
    scene, folder = load_scene(scene_file)
    assert scene.camera.position == (0.0, 0.0, 20.0)
    assert scene.materials["Red"] == spec.Diffuse(reflectance=(0.2, 0.3, 0.4))
    assert [o.name for o in scene.objects] == ["mesh_0", "sun disk"]
    assert scene.objects[0].shape.path == "assets/model.glb"
    assert not any(n.startswith("camera:") for n in scene.notes)
    assert compile_scene(scene, folder).num_triangles > 6
    scene_file.write_text(yaml.safe_dump({"import": "../model.glb"}))
    with pytest.raises(SceneError) as caught:
        load_scene(scene_file)
    assert caught.value.field == "import"


def normal_mapped_quad(tmp_path, texel, uvs=None) -> PathTracer:
    builder = GltfBuilder()
    normal = builder.texture(builder.image(np.full((2, 2, 3), texel, np.uint8)))
    material = builder.material(name="Bumpy", normalTexture={"index": normal})
    mesh = (
        quad(builder, material)
        if uvs is None
        else builder.mesh(
            QUAD_POSITIONS,
            [[0, 1, 2], [0, 2, 3]],
            normals=np.tile([0, 0, 1.0], (4, 1)),
            uvs=uvs,
            material=material,
        )
    )
    builder.node(mesh=mesh)
    builder.light(type="directional")
    scene, folder = load_scene(builder.save(tmp_path / f"bump{len(list(tmp_path.iterdir()))}.glb"))
    return PathTracer(compile_scene(scene, folder))


def shading_normal(tracer: PathTracer) -> np.ndarray:
    o, d = np.array([[0.1, 0.2, 3.0]]), np.array([[0.0, 0.0, -1.0]])
    return tracer.shade(tracer.rays.intersect(o, d), o, d).ns[0]


def tilt(x: float, y: float) -> tuple[int, int, int]:
    """The 8-bit texel of the tangent-space normal (x, y, sqrt(1 - x^2 - y^2))."""
    n = np.array([x, y, math.sqrt(1 - x * x - y * y)])
    return tuple(np.round((n + 1) / 2 * 255).astype(int))


def test_normal_maps_bend_along_u_and_up_the_image_with_generated_tangents(tmp_path):
    """glTF's convention: red follows +u, green points up the image (v grows downwards)."""
    along_u = shading_normal(normal_mapped_quad(tmp_path, tilt(0.5, 0.0)))
    np.testing.assert_allclose(along_u, [0.5, 0.0, math.sqrt(0.75)], atol=0.01)  # u runs along +x
    up = shading_normal(normal_mapped_quad(tmp_path, tilt(0.0, 0.5)))
    np.testing.assert_allclose(up, [0.0, 0.5, math.sqrt(0.75)], atol=0.01)  # the image's top is +y
    flat = shading_normal(normal_mapped_quad(tmp_path, (128, 128, 255)))
    np.testing.assert_allclose(flat, [0, 0, 1], atol=0.01)
    mirrored = np.array([[1, 1], [0, 1], [0, 0], [1, 0]], np.float32)  # u runs along -x now
    bent = shading_normal(normal_mapped_quad(tmp_path, tilt(0.5, 0.0), uvs=mirrored))
    np.testing.assert_allclose(bent, [-0.5, 0.0, math.sqrt(0.75)], atol=0.01)
    bent = shading_normal(normal_mapped_quad(tmp_path, tilt(0.0, 0.5), uvs=mirrored))
    np.testing.assert_allclose(bent, [0.0, 0.5, math.sqrt(0.75)], atol=0.01)  # still up the image


ASSIMP_GLTF2 = Path("/usr/share/assimp/models/glTF2")  # Debian `assimp-testmodels` (BSD)


def test_real_files_from_assimp_testmodels_import_or_fail_naming_the_problem():
    """Khronos' BoxTextured as .gltf, .glb and with embedded buffers is one scene; real bad files fail."""
    if not ASSIMP_GLTF2.is_dir():
        pytest.fail(f"{ASSIMP_GLTF2} is missing: `make test-packages` installs Debian's assimp-testmodels")
    compiled = []
    for name in ("BoxTextured-glTF/BoxTextured.gltf", "BoxTextured-glTF-Binary/BoxTextured.glb",
                 "BoxTextured-glTF-Embedded/BoxTextured.gltf"):  # fmt: skip
        scene, folder = load_scene(ASSIMP_GLTF2 / name)
        tracer = PathTracer(compile_scene(scene, folder))
        compiled.append(tracer)
        material = next(iter(scene.materials.values()))
        assert material.base_color_texture is not None and material.base_color_texture.color_space == "srgb"
    for other in compiled[1:]:
        np.testing.assert_array_equal(other.scene.positions, compiled[0].scene.positions)
        np.testing.assert_array_equal(other.scene.uvs, compiled[0].scene.uvs)
    surf = [
        t.materials.surfaces(np.zeros(4, np.int64), np.random.default_rng(0).random((4, 2))) for t in compiled
    ]
    np.testing.assert_array_equal(surf[0].base, surf[1].base)
    np.testing.assert_array_equal(surf[0].base, surf[2].base)

    scene, _ = load_scene(ASSIMP_GLTF2 / "2CylinderEngine-glTF-Binary/2CylinderEngine.glb")
    assert len(scene.objects) > 20 and any("degenerate" in n for n in scene.notes)
    for name, field, problem in [
        ("draco/2CylinderEngine.gltf", "extensionsRequired", "KHR_draco_mesh_compression"),
        ("IncorrectVertexArrays/Cube.gltf", "nodes[2] (Lines).mesh", "LINES"),
        (
            "IndexOutOfRange/IndexOutOfRange.gltf",
            "IndexOutOfRange.gltf (meshes[0].primitives[0])",
            "past the 24 vertices",
        ),
        ("MissingBin/BoxTextured.gltf", "BoxTextured.gltf: buffers[0].uri", "missing"),
        ("RecursiveNodes/RecursiveNodes.gltf", "nodes[0]", "not a tree"),
    ]:
        with pytest.raises(SceneError, match=problem) as caught:
            load_scene(ASSIMP_GLTF2 / name)
        assert caught.value.field == field, caught.value


def test_values_our_format_cannot_hold_are_scene_errors(tmp_path):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder, builder.material(pbrMetallicRoughness={"baseColorFactor": [2, 0, 0, 1]})))
    with pytest.raises(SceneError, match="base_color") as caught:
        load_scene(builder.save(tmp_path / "bright.glb"))
    assert caught.value.field == "bright.glb"
