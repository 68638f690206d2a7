"""A mesh file must not make us read files outside its folder (uploaded scenes are untrusted)."""

import json
from pathlib import Path

import pytest
import trimesh

from workers.scene.format.errors import SceneError
from workers.scene.importers.meshio import load_mesh_file


@pytest.mark.parametrize("reference", ["../outside.bin", "ABSOLUTE"])
def test_gltf_buffers_outside_the_mesh_folder_are_refused(tmp_path, reference):
    folder = tmp_path / "upload"
    folder.mkdir()
    trimesh.creation.box().export(folder / "box.gltf")
    gltf = json.loads((folder / "box.gltf").read_text())
    inside = folder / gltf["buffers"][0]["uri"]
    outside = tmp_path / "outside.bin"
    outside.write_bytes(inside.read_bytes())  # a valid buffer, just in the wrong place
    inside.unlink()
    gltf["buffers"][0]["uri"] = str(outside) if reference == "ABSOLUTE" else reference
    (folder / "box.gltf").write_text(json.dumps(gltf))
    with pytest.raises(SceneError) as error:
        load_mesh_file(folder / "box.gltf", "objects[0].shape.path")
    assert error.value.field == "objects[0].shape.path"


def test_obj_material_library_outside_the_folder_is_not_read(tmp_path):
    folder = tmp_path / "upload"
    folder.mkdir()
    secret = tmp_path / "secret.mtl"
    secret.write_text("newmtl leaked\nKd 1 0 0\n")
    obj = folder / "tri.obj"
    obj.write_text("mtllib ../secret.mtl\nusemtl leaked\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh = load_mesh_file(Path(obj), "objects[0].shape.path")  # geometry loads; the library does not
    assert mesh.num_triangles == 1
    loaded = trimesh.load(str(obj), process=False)
    material = getattr(loaded.visual, "material", None)
    assert getattr(material, "name", None) != "leaked"
