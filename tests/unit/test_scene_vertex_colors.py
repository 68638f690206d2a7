"""Vertex colours multiply the material's base colour: read from glTF's COLOR_0 (floats or normalized
integers, linear), from OBJ and PLY files (8-bit display values, decoded to linear; a PLY's face colours
kept per face), interpolated across each triangle by the path tracer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from tests.support.gltf_files import QUAD_POSITIONS, GltfBuilder, quad
from workers.render.camera import PinholeCamera
from workers.render.render import RenderSettings, render
from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.compile import compile_scene
from workers.scene.geometry.mesh import MeshData
from workers.scene.geometry.shapes import check_mesh
from workers.scene.importers.image_io import srgb_to_linear
from workers.scene.importers.meshio import load_mesh_file
from workers.scene.portability.io import load_scene

# Per quad corner: red grows along +x, green along +y, blue is constant (affine, so interpolation is exact).
QUAD_COLORS = np.stack(
    [(QUAD_POSITIONS[:, 0] + 1) / 2, (QUAD_POSITIONS[:, 1] + 1) / 2, np.full(4, 0.5)], axis=1
)


def compiled(path):
    return compile_scene(*load_scene(path))


def coloured_quad_scene(tmp_path, albedo, radiance) -> spec.SceneSpec:
    """A glTF quad with QUAD_COLORS, made diffuse, under a constant environment, seen from +z."""
    builder = GltfBuilder()
    builder.node(mesh=quad(builder, colors=QUAD_COLORS))
    scene, _ = load_scene(builder.save(tmp_path / "quad.glb"))
    (name,) = scene.materials
    return scene.model_copy(
        update={
            "materials": {name: spec.Diffuse(reflectance=tuple(albedo))},
            "environment": spec.ConstantBackground(radiance=tuple(radiance)),
            "lights": [],
            "camera": spec.Camera(position=(0, 0, 4), target=(0, 0, 0), fov=20, width=12, height=12),
        }
    )


def test_gltf_color_0_is_imported_and_no_longer_listed_as_ignored(tmp_path):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder, colors=np.c_[QUAD_COLORS, np.full(4, 0.25)]))  # RGBA: alpha dropped
    scene, folder = load_scene(builder.save(tmp_path / "quad.glb"))
    assert not any("COLOR_0" in note for note in scene.notes)
    compiled = compile_scene(scene, folder)
    assert compiled.vertex_colors.shape == (2, 3, 3)
    corners = compiled.positions.reshape(-1, 3)
    expected = np.stack([(corners[:, 0] + 1) / 2, (corners[:, 1] + 1) / 2, np.full(len(corners), 0.5)], 1)
    np.testing.assert_allclose(compiled.vertex_colors.reshape(-1, 3), expected, atol=1e-6)


def test_a_scene_without_vertex_colours_carries_none(tmp_path):
    builder = GltfBuilder()
    builder.node(mesh=quad(builder))
    assert compiled(builder.save(tmp_path / "quad.glb")).vertex_colors is None


def test_the_path_tracer_multiplies_the_base_colour_by_the_interpolated_vertex_colour(tmp_path):
    """With the same random numbers, the coloured plane's image over the uncoloured one's is the colour
    at the pixel's hit points, weighted by their radiance: within half the 0.06 a pixel spans of the
    centre's colour (exactly the constant blue)."""
    scene = coloured_quad_scene(tmp_path, albedo=(0.8, 0.6, 0.9), radiance=(1.5, 1.0, 2.0))
    coloured = compile_scene(scene, tmp_path)
    settings = RenderSettings(spp=16, max_depth=2, seed=1)
    ratio = render(coloured, settings).image / render(replace(coloured, vertex_colors=None), settings).image
    cam = scene.camera
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
    origins, directions = PinholeCamera(cam).rays(xs.ravel() + 0.5, ys.ravel() + 0.5)
    hit = origins + directions * (-origins[:, 2:] / directions[:, 2:])  # on the plane z = 0
    colour = np.stack([(hit[:, 0] + 1) / 2, (hit[:, 1] + 1) / 2, np.full(len(hit), 0.5)], axis=1)
    np.testing.assert_allclose(ratio.reshape(-1, 3), colour, atol=0.03)


def test_normalized_byte_colours_of_a_glb_are_linear(tmp_path):
    """trimesh writes COLOR_0 as normalized unsigned bytes; glTF defines them as linear."""
    box = trimesh.creation.box()
    box.visual.face_colors = [200, 30, 30, 255]
    box.export(tmp_path / "box.glb")
    colours = compiled(tmp_path / "box.glb").vertex_colors.reshape(-1, 3)
    np.testing.assert_allclose(colours, [[200 / 255, 30 / 255, 30 / 255]] * 36)


def test_ply_face_colours_stay_per_face_and_are_decoded_from_srgb(tmp_path):
    box = trimesh.creation.box()
    colours = np.zeros((12, 4), np.uint8)
    colours[:, 3] = 255
    colours[:, 0] = np.arange(12) * 20  # every face its own red
    box.visual.face_colors = colours
    box.export(tmp_path / "box.ply")
    mesh = load_mesh_file(tmp_path / "box.ply", "f")
    per_corner = mesh.colors[mesh.faces]  # (12, 3, 3): a face's three corners agree, no blur over edges
    np.testing.assert_allclose(per_corner[:, 0, 0], srgb_to_linear(np.arange(12) * 20 / 255), atol=1e-6)
    np.testing.assert_array_equal(per_corner, per_corner[:, :1].repeat(3, axis=1))


def test_obj_vertex_colours_are_decoded_from_srgb(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0 1 0.5 0\nv 1 0 0 1 0.5 0\nv 0 1 0 1 0.5 0\nf 1 2 3\n")
    mesh = load_mesh_file(tmp_path / "t.obj", "f")
    np.testing.assert_allclose(mesh.colors, srgb_to_linear(np.array([[255, 128, 0]] * 3) / 255), atol=1e-6)


@pytest.mark.parametrize("bad", [np.nan, -0.5])
def test_malformed_vertex_colours_are_a_scene_error(bad):
    colors = np.full((3, 3), 0.5)
    colors[1, 2] = bad
    mesh = MeshData(np.eye(3), np.array([[0, 1, 2]]), colors=colors)
    with pytest.raises(SceneError, match="vertex colours"):
        check_mesh(mesh, "objects[0].shape")
