"""Scene uploads: loose files and archives become one validated asset; every bad input is refused."""

import io
import stat
import tarfile
import zipfile

import pytest
import trimesh
from PIL import Image

from services.artifacts.assets import AssetNotFound, load_asset, materialize, save_asset
from services.artifacts.store import BlobCorrupted, BlobStore
from services.artifacts.uploads import UploadError, UploadLimits, ingest_upload
from tests.support.archives import tarred, zipped
from workers.scene.format.errors import SceneError
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import load_scene

SCENE = """\
name: uploaded
materials:
  grey: {type: diffuse, reflectance: [0.5, 0.5, 0.5]}
  painted: {type: diffuse, reflectance: {type: image, path: textures/albedo.png}}
objects:
  - name: box
    shape: {type: mesh, path: meshes/box.obj}
    material: grey
  - name: ball
    shape: {type: sphere, radius: 0.3, subdivisions: 1}
    material: painted
lights:
  - {type: point, position: [0, 5, 0], intensity: [10, 10, 10]}
"""
BOX_OBJ = trimesh.creation.box().export(file_type="obj").encode()


def png_bytes() -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (2, 2), (200, 100, 50)).save(buffer, format="PNG")
    return buffer.getvalue()


PNG_BYTES = png_bytes()


def scene_files(**changes: bytes | None) -> dict[str, bytes]:
    files = {"scene.yaml": SCENE.encode(), "meshes/box.obj": BOX_OBJ, "textures/albedo.png": PNG_BYTES}
    files.update(changes)
    return {name: data for name, data in files.items() if data is not None}


def loose(files: dict[str, bytes]) -> list[tuple[str, io.BytesIO]]:
    return [(name, io.BytesIO(data)) for name, data in files.items()]


@pytest.fixture
def blobs(tmp_path):
    return BlobStore(str(tmp_path / "store"))


def nothing_stored(blobs: BlobStore) -> bool:
    return list(blobs.digests()) == []


def upload_error(parts, blobs, limits=None) -> UploadError:
    with pytest.raises(UploadError) as caught:
        ingest_upload(parts, blobs, limits or UploadLimits())
    assert nothing_stored(blobs)
    return caught.value


def scene_error(parts, blobs) -> SceneError:
    with pytest.raises(SceneError) as caught:
        ingest_upload(parts, blobs, UploadLimits())
    assert nothing_stored(blobs)
    return caught.value


# --------------------------------------------------------------------------- good uploads


def test_a_scene_with_its_mesh_and_texture_becomes_an_asset(blobs):
    asset = ingest_upload(loose(scene_files()), blobs, UploadLimits())
    assert asset.scene_file == "scene.yaml" and asset.scene_name == "uploaded"
    by_name = {entry.name: entry for entry in asset.files}
    assert list(by_name) == ["meshes/box.obj", "scene.yaml", "textures/albedo.png"]
    assert by_name["meshes/box.obj"].media_type == "model/obj"
    assert by_name["textures/albedo.png"].media_type == "image/png"
    assert blobs.read(by_name["meshes/box.obj"].digest) == BOX_OBJ
    assert asset.is_intact()


def test_loose_files_zip_and_tar_give_the_same_asset_id(blobs):
    files = scene_files()
    ids = {
        ingest_upload(loose(files), blobs, UploadLimits()).asset_id,
        ingest_upload(loose(files), blobs, UploadLimits()).asset_id,
        ingest_upload(zipped(files), blobs, UploadLimits()).asset_id,
        ingest_upload(tarred(files), blobs, UploadLimits()).asset_id,
        ingest_upload(
            tarred({f"./{n}": d for n, d in files.items()}, "s.tar"), blobs, UploadLimits()
        ).asset_id,
    }
    assert len(ids) == 1


def test_different_content_gives_a_different_id(blobs):
    first = ingest_upload(loose(scene_files()), blobs, UploadLimits())
    second = ingest_upload(loose(scene_files(**{"extra/notes.txt": b"hi"})), blobs, UploadLimits())
    assert first.asset_id != second.asset_id


def test_an_archive_with_a_top_folder_and_macos_litter(blobs):
    files = {f"myscene/{name}": data for name, data in scene_files().items()}
    files |= {"__MACOSX/myscene/._scene.yaml": b"\x00\x05", "myscene/.DS_Store": b"\x00"}
    asset = ingest_upload(zipped(files), blobs, UploadLimits())
    assert asset.scene_file == "myscene/scene.yaml"
    assert len(asset.files) == 3


def test_save_load_and_materialize_round_trip(blobs, tmp_path):
    root = str(tmp_path / "store")
    asset = ingest_upload(zipped(scene_files()), blobs, UploadLimits())
    save_asset(asset, blobs, root)
    loaded = load_asset(asset.asset_id, root)
    assert loaded == asset
    scene_path = materialize(loaded, blobs, tmp_path / "unpacked")
    assert scene_path == tmp_path / "unpacked" / "scene.yaml"
    for name, data in scene_files().items():
        assert (tmp_path / "unpacked" / name).read_bytes() == data
    spec, base = load_scene(scene_path)
    assert compile_scene(spec, base).num_triangles > 12


def test_saving_again_keeps_the_first_upload_time(blobs, tmp_path):
    root = str(tmp_path / "store")
    first = ingest_upload(loose(scene_files()), blobs, UploadLimits())
    save_asset(first, blobs, root)
    save_asset(ingest_upload(loose(scene_files()), blobs, UploadLimits()), blobs, root)
    assert load_asset(first.asset_id, root).created == first.created


def test_unknown_and_tampered_assets(blobs, tmp_path):
    root = str(tmp_path / "store")
    with pytest.raises(AssetNotFound):
        load_asset("sha256:" + "0" * 64, root)
    with pytest.raises(ValueError, match="not a digest"):
        load_asset("../../etc/passwd", root)
    asset = ingest_upload(loose(scene_files()), blobs, UploadLimits())
    save_asset(asset, blobs, root)
    listing = tmp_path / "store" / "assets" / f"{asset.asset_id.removeprefix('sha256:')}.json"
    listing.write_text(listing.read_text().replace("meshes/box.obj", "../../../tmp/x.obj"))
    with pytest.raises(BlobCorrupted):
        load_asset(asset.asset_id, root)


def test_materialize_refuses_a_listing_that_escapes(blobs, tmp_path):
    asset = ingest_upload(loose(scene_files()), blobs, UploadLimits())
    files = [entry.model_copy(update={"name": "../escaped.obj"}) for entry in asset.files]
    with pytest.raises(ValueError, match=r"\.\."):
        materialize(asset.model_copy(update={"files": files}), blobs, tmp_path / "out")
    assert not (tmp_path / "escaped.obj").exists()


# --------------------------------------------------------------------------- bad containers


@pytest.mark.parametrize("name", ["../x.obj", "/etc/passwd", "C:/x.obj", "meshes\\a.obj", "a/../../x.obj"])
@pytest.mark.parametrize("pack", [loose, zipped, tarred])
def test_path_traversal_is_refused(blobs, pack, name):
    error = upload_error(pack(scene_files(**{name: b"v 0 0 0\n"})), blobs)
    assert error.field == name and error.status == 400


@pytest.mark.parametrize(("kind", "what"), [(tarfile.SYMTYPE, "symlink"), (tarfile.LNKTYPE, "hardlink")])
def test_links_in_tars_are_refused(blobs, kind, what):
    parts = tarred(scene_files(), links={"meshes/link.obj": (kind, "/etc/passwd")})
    error = upload_error(parts, blobs)
    assert error.field == "meshes/link.obj" and what in error.problem


def test_devices_in_tars_are_refused(blobs):
    error = upload_error(tarred(scene_files(), links={"dev/null": (tarfile.CHRTYPE, "")}), blobs)
    assert error.field == "dev/null" and "special files" in error.problem


def test_symlinks_in_zips_are_refused(blobs):
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in scene_files().items():
            archive.writestr(name, data)
        link = zipfile.ZipInfo("meshes/link.obj")
        link.external_attr = (stat.S_IFLNK | 0o777) << 16
        archive.writestr(link, "/etc/passwd")
    error = upload_error([("scene.zip", io.BytesIO(buffer.getvalue()))], blobs)
    assert error.field == "meshes/link.obj" and "symlink" in error.problem


def test_a_zip_bomb_is_refused_from_its_declared_sizes(blobs):
    parts = zipped(scene_files(**{"meshes/huge.obj": bytes(20 << 20)}))
    assert len(parts[0][1].getvalue()) < 1 << 20
    error = upload_error(parts, blobs)
    assert error.status == 413 and "decompression bomb" in error.problem and error.field == "meshes/huge.obj"


def test_a_tar_gz_bomb_is_refused_while_reading(blobs):
    error = upload_error(tarred(scene_files(**{"meshes/huge.obj": bytes(20 << 20)})), blobs)
    assert error.status == 413 and "decompression bomb" in error.problem


def test_too_many_files(blobs):
    limits = UploadLimits(max_files=3)
    files = scene_files(**{"notes/a.txt": b"a", "notes/b.txt": b"b"})
    for parts in (loose(files), zipped(files), tarred(files)):
        error = upload_error(parts, blobs, limits)
        assert error.status == 413 and "too many files" in error.problem


def test_files_and_uploads_that_are_too_large(blobs):
    big = scene_files(**{"textures/big.png": bytes(5000)})
    for pack in (loose, zipped, tarred):
        error = upload_error(pack(big), blobs, UploadLimits(max_file_bytes=4096))
        assert error.status == 413 and error.field == "textures/big.png"
        error = upload_error(pack(big), blobs, UploadLimits(max_total_bytes=4096))
        assert error.status == 413 and "bytes in total" in error.problem


@pytest.mark.parametrize(
    "parts",
    [[], zipped({}), tarred({}), zipped({"empty/": b""})],
    ids=["nothing", "empty zip", "empty tar", "only a folder"],
)
def test_empty_uploads(blobs, parts):
    error = upload_error(parts, blobs)
    assert error.status == 400 and error.field == "files"


def test_an_empty_mesh_is_refused(blobs):
    error = upload_error(loose(scene_files(**{"meshes/box.obj": b""})), blobs)
    assert error.field == "meshes/box.obj" and "empty" in error.problem


@pytest.mark.parametrize(
    ("parts", "field", "problem"),
    [
        (loose(scene_files()) + loose({"scene.yaml": b"name: again\n"}), "scene.yaml", "duplicate"),
        (loose(scene_files(**{"Scene.yaml": b"name: case\n"})), "Scene.yaml", "duplicate"),
        (tarred(scene_files(**{"./scene.yaml": b"name: dot\n"})), "scene.yaml", "duplicate"),
        (loose(scene_files(**{"meshes/box.obj/inner.obj": BOX_OBJ})), "meshes/box.obj/inner.obj", "both"),
    ],
    ids=["same name twice", "differs only in case", "same after normalising", "file and folder"],
)
def test_clashing_names_are_refused(blobs, parts, field, problem):
    error = upload_error(parts, blobs)
    assert error.field == field and problem in error.problem


def test_an_archive_must_come_alone(blobs):
    error = upload_error(zipped(scene_files()) + loose({"extra.txt": b"x"}), blobs)
    assert "one archive" in error.problem


def test_a_corrupt_archive_is_a_bad_request(blobs):
    error = upload_error([("scene.zip", io.BytesIO(b"PK\x03\x04 not really a zip"))], blobs)
    assert error.status == 400 and error.field == "scene.zip"
    error = upload_error([("scene.tgz", io.BytesIO(b"\x1f\x8b\x08 truncated"))], blobs)
    assert error.status == 400 and error.field == "scene.tgz"


def test_the_scene_file_must_be_found_unambiguously(blobs):
    error = upload_error(loose({"meshes/box.obj": BOX_OBJ}), blobs)
    assert "no scene file" in error.problem
    error = upload_error(loose({"a.yaml": SCENE.encode(), "b.json": b"{}", "meshes/box.obj": BOX_OBJ}), blobs)
    assert "a.yaml, b.json" in error.problem


# --------------------------------------------------------------------------- bad scenes


def test_a_missing_mesh_names_the_field(blobs):
    error = scene_error(loose(scene_files(**{"meshes/box.obj": None})), blobs)
    assert error.field == "objects[0].shape.path" and "meshes/box.obj" in error.problem
    assert "upload the scene's folder" in error.problem  # a user who sent the scene file alone learns how


def test_a_missing_texture_names_the_field(blobs):
    error = scene_error(loose(scene_files(**{"textures/albedo.png": None})), blobs)
    assert error.field == "materials.painted.reflectance.path"


@pytest.mark.parametrize("reference", ["../outside.obj", "/etc/passwd", "C:/x.obj", "meshes\\box.obj"])
def test_scene_references_cannot_leave_the_upload(blobs, reference):
    scene = SCENE.replace("meshes/box.obj", reference).encode()
    error = scene_error(loose(scene_files(**{"scene.yaml": scene})), blobs)
    assert error.field == "objects[0].shape.path"


def test_references_resolve_from_the_scene_files_folder(blobs):
    files = {"scenes/scene.yaml": SCENE.replace("meshes/", "../meshes/").replace("textures/", "../textures/")}
    files = scene_files(**{"scene.yaml": None, **{k: v.encode() for k, v in files.items()}})
    assert ingest_upload(loose(files), blobs, UploadLimits()).scene_file == "scenes/scene.yaml"


def test_an_invalid_scene_names_the_field(blobs):
    scene = SCENE.replace("lights:", "camera: {fov: 500}\nlights:").encode()
    error = scene_error(loose(scene_files(**{"scene.yaml": scene})), blobs)
    assert error.field == "camera.fov"


def test_malformed_yaml_names_the_file_inside_the_upload(blobs):
    error = scene_error(loose(scene_files(**{"scene.yaml": b"name: x\nmaterials: {grey: [1, 2\n"})), blobs)
    assert error.field == "scene.yaml" and "malformed YAML at line" in error.problem
    assert "nbake-upload" not in str(error)


@pytest.mark.parametrize(
    ("obj", "problem"),
    [
        (b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "NaN"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n", "degenerate"),
    ],
)
def test_broken_geometry_is_caught_at_upload(blobs, obj, problem):
    error = scene_error(loose(scene_files(**{"meshes/box.obj": obj})), blobs)
    assert error.field == "objects[0].shape" and problem in error.problem
