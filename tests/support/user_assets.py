"""A built-in scene as a user would upload it: a folder with `scene.yaml` and its geometry in files of
their own, the formats users bring. The object with the most triangles (what a kind models) becomes an
OBJ with its MTL, the next one a glTF with external buffers; both keep their normals and UVs, transforms
and materials, so the folder is the same scene and every kind's example trains on it as on the built-in.
"""

from __future__ import annotations

import trimesh
import yaml

from workers.scene.format.spec import SceneSpec
from workers.scene.geometry.mesh import MeshData
from workers.scene.geometry.shapes import shape_mesh


def trimesh_of(mesh: MeshData) -> trimesh.Trimesh:
    visual = None if mesh.uvs is None else trimesh.visual.TextureVisuals(uv=mesh.uvs)
    return trimesh.Trimesh(
        mesh.vertices, mesh.faces, vertex_normals=mesh.normals, visual=visual, process=False
    )


def obj_files(mesh: MeshData, folder: str) -> tuple[str, dict[str, bytes]]:
    """(the OBJ's path, the folder's files): the OBJ and the MTL it names."""
    text, extra = trimesh.exchange.obj.export_obj(
        trimesh_of(mesh), include_normals=mesh.normals is not None, include_texture=True, return_texture=True
    )
    files = {f"{folder}/mesh.obj": text.encode()} | {f"{folder}/{n}": data for n, data in extra.items()}
    return f"{folder}/mesh.obj", files


def gltf_files(mesh: MeshData, folder: str) -> tuple[str, dict[str, bytes]]:
    """(the .gltf's path, the folder's files): the JSON and the binary buffers it references."""
    exported = trimesh_of(mesh).export(file_type="gltf")
    return f"{folder}/model.gltf", {f"{folder}/{name}": data for name, data in exported.items()}


def modelled_objects(scene: SceneSpec) -> list[int]:
    """Indices of the objects that do not emit, most triangles first (ties: scene order)."""
    counts = {
        i: shape_mesh(obj.shape, f"objects[{i}].shape").num_triangles
        for i, obj in enumerate(scene.objects)
        if obj.emission is None
    }
    return sorted(counts, key=lambda i: (-counts[i], i))


def user_folder(scene: SceneSpec, name: str) -> dict[str, bytes]:
    """The upload: path in the folder -> bytes."""
    document = scene.model_dump(mode="json", exclude_none=True)
    document["name"] = name
    files: dict[str, bytes] = {}
    for index, (export, shape_type) in zip(
        modelled_objects(scene), [(obj_files, "mesh"), (gltf_files, "gltf")], strict=False
    ):
        obj = document["objects"][index]
        mesh = shape_mesh(scene.objects[index].shape, f"objects[{index}].shape")
        path, written = export(mesh, f"meshes/{obj['name']}")
        files |= written
        obj["shape"] = {"type": shape_type, "path": path}
    return {"scene.yaml": yaml.safe_dump(document).encode(), **files}
