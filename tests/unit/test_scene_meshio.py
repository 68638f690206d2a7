"""Mesh files: every format loads into one MeshData, node transforms apply, bad files become SceneErrors."""

import numpy as np
import pytest
import trimesh

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.shapes import shape_mesh
from workers.scene.importers.meshio import load_mesh_file

TWO_GROUP_OBJ = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 2
v 1 0 2
v 1 1 2
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
o first
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
o second
f 5/1/1 6/2/1 7/3/1
"""


def face_normals(vertices, faces):
    n = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_obj_with_objects_keeps_uvs_and_normals(tmp_path):
    (tmp_path / "m.obj").write_text(TWO_GROUP_OBJ)
    mesh = load_mesh_file(tmp_path / "m.obj", "f")
    assert mesh.num_triangles == 3
    corners = mesh.vertices[mesh.faces]
    assert {tuple(p) for p in corners.reshape(-1, 3)} == {
        (0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 2), (1, 0, 2), (1, 1, 2)
    }  # fmt: skip
    np.testing.assert_allclose(mesh.normals, np.tile([0.0, 0.0, 1.0], (len(mesh.vertices), 1)))
    # UVs follow the vertex they were written with, flipped to Mitsuba's top-left origin
    for vertex, uv in zip(mesh.vertices, mesh.uvs, strict=True):
        np.testing.assert_allclose(uv, [vertex[0], 1.0 - vertex[1]])


def test_obj_without_normals_gets_none(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh = load_mesh_file(tmp_path / "t.obj", "f")
    assert mesh.normals is None and mesh.uvs is None


@pytest.mark.parametrize("extension", ["ply", "stl", "glb", "obj"])
def test_single_mesh_formats_round_trip(tmp_path, extension):
    source = trimesh.creation.icosphere(subdivisions=2)
    path = tmp_path / f"ico.{extension}"
    source.export(path)
    mesh = load_mesh_file(path, "f")
    assert mesh.num_triangles == len(source.faces)
    # same surface whatever the vertex order: compare sorted triangle centroids
    got = np.sort(mesh.vertices[mesh.faces].mean(axis=1).round(5), axis=0)
    want = np.sort(source.triangles.mean(axis=1).round(5), axis=0)
    np.testing.assert_allclose(got, want, atol=1e-5)
    # winding survives: normals point away from the centre
    assert (
        np.einsum("ij,ij->i", face_normals(mesh.vertices, mesh.faces), mesh.vertices[mesh.faces[:, 0]]) > 0
    ).all()


def test_gltf_scene_flattens_node_transforms_and_mirrors_keep_normals_outward(tmp_path):
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(
        box, node_name="moved", transform=trimesh.transformations.translation_matrix([3, 0, 0])
    )
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [-3, 0, 0]
    scene.add_geometry(box, node_name="mirrored", transform=mirror)
    for name in ("s.glb", "s.gltf"):
        if name.endswith(".gltf"):
            files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)
            (tmp_path / name).write_bytes(files["model.gltf"])
        else:
            scene.export(tmp_path / name)
        mesh = load_mesh_file(tmp_path / name, "f")
        assert mesh.num_triangles == 24
        centroids = mesh.vertices[mesh.faces].mean(axis=1)
        centres = np.where(centroids[:, :1] > 0, [3.0, 0, 0], [-3.0, 0, 0])
        assert sorted(np.unique(centres[:, 0])) == [-3.0, 3.0]
        outward = np.einsum("ij,ij->i", face_normals(mesh.vertices, mesh.faces), centroids - centres)
        assert (outward > 0).all()


def test_glb_uvs_survive(tmp_path):
    plane = trimesh.Trimesh(
        vertices=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 2, 3]], process=False
    )
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    plane.visual = trimesh.visual.TextureVisuals(uv=uv)
    plane.export(tmp_path / "p.glb")
    mesh = load_mesh_file(tmp_path / "p.glb", "f")
    assert mesh.uvs is not None
    np.testing.assert_allclose(mesh.uvs, np.stack([mesh.vertices[:, 0], 1.0 - mesh.vertices[:, 1]], axis=1))


@pytest.mark.parametrize(
    ("name", "content", "problem"),
    [
        ("garbage.glb", b"definitely not a glb", "cannot read"),
        (
            "garbage.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n",
            "cannot read",
        ),
        ("points.obj", b"v 0 0 0\nv 1 0 0\n", "no triangles"),
        ("model.fbx", b"", "unsupported mesh format"),
    ],
)
def test_unusable_files_raise_scene_errors(tmp_path, name, content, problem):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(SceneError, match=problem) as caught:
        load_mesh_file(tmp_path / name, "objects[0].shape.path")
    assert caught.value.field == "objects[0].shape.path"


def test_missing_file_names_the_path_field(tmp_path):
    shape = spec.MeshShape(path="nowhere.obj")
    with pytest.raises(SceneError, match="not found") as caught:
        shape_mesh(shape, "objects[3].shape", tmp_path)
    assert caught.value.field == "objects[3].shape.path"


def test_nan_vertices_are_rejected(tmp_path):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 inf 1\nf 1 2 3\nf 1 2 4\n")
    with pytest.raises(SceneError, match="NaN or Inf") as caught:
        shape_mesh(spec.MeshShape(path="nan.obj"), "objects[0].shape", tmp_path)
    assert caught.value.field == "objects[0].shape"


def test_degenerate_triangles_are_rejected_unless_repaired(tmp_path):
    (tmp_path / "d.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    with pytest.raises(SceneError, match="degenerate"):
        shape_mesh(spec.MeshShape(path="d.obj"), "objects[0].shape", tmp_path)
    repaired = shape_mesh(spec.MeshShape(path="d.obj", repair=True), "objects[0].shape", tmp_path)
    assert repaired.num_triangles == 1
