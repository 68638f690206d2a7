"""A textured glTF scene (metallic-roughness materials: a textured dielectric floor, a rough metal, glass
and a blend; an emissive panel and a point light) rendered by our path tracer and by Mitsuba 3's
`principled` on the same triangles agree within noise (tests/integration/test_render_vs_mitsuba.py)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.integration.test_render_vs_mitsuba import compare
from tests.support.gltf_files import GltfBuilder, quad
from workers.scene.portability.io import load_scene

mi = pytest.importorskip("mitsuba")
pytestmark = [pytest.mark.mitsuba, pytest.mark.slow]

H = 0.7071068  # cos 45 degrees


def sphere(builder: GltfBuilder, material: int) -> int:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    normals = ball.vertices / np.linalg.norm(ball.vertices, axis=1, keepdims=True)
    return builder.mesh(ball.vertices, ball.faces, normals=normals, material=material)


def textured_gltf_scene(folder) -> object:
    builder = GltfBuilder()
    checker = np.zeros((8, 8, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = (230, 200, 120)
    checker[1::2, ::2] = checker[::2, 1::2] = (40, 90, 160)
    floor = builder.material(
        name="Floor",
        pbrMetallicRoughness={
            "baseColorTexture": {"index": builder.texture(builder.image(checker, uri="checker.png"))},
            "metallicFactor": 0.0,
            "roughnessFactor": 0.7,
        },
    )
    gold = builder.material(
        name="Gold", pbrMetallicRoughness={"baseColorFactor": [1.0, 0.77, 0.34, 1], "roughnessFactor": 0.4}
    )
    builder.use("KHR_materials_transmission")
    builder.use("KHR_materials_ior")
    glass = builder.material(
        name="Glass",
        pbrMetallicRoughness={"metallicFactor": 0.0, "roughnessFactor": 0.3},
        extensions={
            "KHR_materials_transmission": {"transmissionFactor": 1.0},
            "KHR_materials_ior": {"ior": 1.5},
        },
    )
    blend = builder.material(
        name="Blend",
        pbrMetallicRoughness={
            "baseColorFactor": [0.2, 0.6, 0.3, 1],
            "metallicFactor": 0.5,
            "roughnessFactor": 0.5,
        },
    )
    lamp = builder.material(
        name="Lamp", emissiveFactor=[1.0, 1.0, 1.0], pbrMetallicRoughness={"metallicFactor": 0.0}
    )
    builder.use("KHR_materials_emissive_strength")
    builder.doc.materials[lamp].extensions = {"KHR_materials_emissive_strength": {"emissiveStrength": 6.0}}
    builder.node(mesh=quad(builder, floor), rotation=[-H, 0, 0, H], scale=[3, 3, 3])
    builder.node(mesh=sphere(builder, gold), translation=[-1.1, 0.5, 0.0])
    builder.node(mesh=sphere(builder, glass), translation=[0.0, 0.5, 0.3])
    builder.node(mesh=sphere(builder, blend), translation=[1.1, 0.5, 0.0])
    builder.node(
        mesh=quad(builder, lamp), translation=[0.0, 2.5, 0.5], rotation=[H, 0, 0, H], scale=[0.6] * 3
    )
    builder.node(
        extensions={"KHR_lights_punctual": {"light": builder.light(type="point", intensity=3.0)}},
        translation=[2.0, 2.0, 2.0],
    )
    builder.node(camera=builder.camera(yfov=0.75), translation=[0.0, 1.6, 4.5], rotation=[-0.17, 0, 0, 0.985])
    return load_scene(builder.save(folder / "scene.gltf"))


def test_textured_gltf_scene_agrees_with_mitsuba_principled(tmp_path):
    """The importer gives the energy-conserving diffuse; principled's is Burley's, so the materials with a
    diffuse lobe (floor, blend, lamp) are switched to `diffuse: burley`. Gold (metallic 1) and glass
    (transmission 1) keep the default: their lobes are the same in both modes, and must match principled."""
    scene, folder = textured_gltf_scene(tmp_path / "gltf")
    assert {m.type for m in scene.materials.values()} == {"pbr"} and not scene.notes
    assert {m.diffuse for m in scene.materials.values()} == {"energy_conserving"}
    materials = {
        name: m if m.metallic == 1 or m.transmission == 1 else m.model_copy(update={"diffuse": "burley"})
        for name, m in scene.materials.items()
    }
    assert sorted(m.diffuse for m in materials.values()) == ["burley"] * 3 + ["energy_conserving"] * 2
    scene = scene.model_copy(update={"materials": materials})
    compare(scene, spp=32, max_depth=8, tmp_path=tmp_path, base_dir=folder)
