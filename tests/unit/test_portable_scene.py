"""The scene an artifact keeps (`workers.scene.portability.portable`) and the parameters of a path-traced
`:render` (`workers.runtime.view_render`): stand-ins keep their objects' placements and enclose their
bounds, the files a scene reads travel with it (verified) and outlive the job's folder and the download, a
scene whose files cannot be kept is refused with the reason, and a camera's given fields override the view's
own."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import trimesh

from tests.unit.test_lsnif_model import instanced_scene
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.view_render import MAX_SAMPLES, CameraParams, ViewRender
from workers.scene.format.spec import (
    Camera,
    Diffuse,
    EnvironmentMap,
    ImageTexture,
    MeshShape,
    SceneObject,
    SphereShape,
)
from workers.scene.geometry.compile import compile_scene
from workers.scene.geometry.framing import framing_camera
from workers.scene.importers.image_io import write_exr, write_png
from workers.scene.portability.portable import (
    NEUTRAL_RADIANCE,
    StoredScene,
    load_scene,
    neutral_scene,
    portable_scene,
    save_scene,
)
from workers.scene.portability.stored import CACHE_ENV

BALL_BOUNDS = np.array([[-0.3, -0.3, -0.3], [0.3, 0.3, 0.3]])


def test_standins_keep_placements_and_enclose_the_bounds_they_replace():
    scene = instanced_scene()
    paint = {"paint": Diffuse(reflectance=ImageTexture(path="ball.png"))}
    ball = scene.objects[-1].model_copy(update={"material": "paint"})
    textured = scene.model_copy(
        update={"objects": [*scene.objects[:-1], ball], "materials": scene.materials | paint}
    )
    stored = portable_scene(textured, {"ball": BALL_BOUNDS})
    assert stored.spec is not None and stored.standins == ("ball",) and stored.reason == ""
    original = compile_scene(scene)
    kept = compile_scene(stored.spec)
    ball, standin = original.objects[-1], kept.objects[-1]
    assert standin.mesh.num_triangles == 20 < ball.mesh.num_triangles
    for before, after in zip(ball.instance_matrices, standin.instance_matrices, strict=True):
        np.testing.assert_array_equal(before, after)
    # the icosahedron's faces lie outside the bounds' sphere, so the box's corners are inside them all
    v, faces = standin.mesh.vertices, standin.mesh.faces
    normals = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    corners = np.array(np.meshgrid(*BALL_BOUNDS.T, indexing="ij")).reshape(3, -1).T
    assert np.all(np.einsum("fk,fck->fc", normals, corners[None] - v[faces[:, 0]][:, None]) <= 1e-9)
    # the ball's material loses its texture (the model predicts the base colour); others are unchanged
    assert stored.spec.materials["paint"].reflectance == (0.5, 0.5, 0.5)
    assert stored.spec.materials["red"] == scene.materials["red"]


def test_a_scene_that_reads_files_is_refused_with_the_fields_at_fault():
    scene = instanced_scene()
    floor = scene.objects[0].model_copy(update={"shape": MeshShape(path="floor.obj")})
    textured = {"red": Diffuse(reflectance=ImageTexture(path="red.png"))}
    reads_files = scene.model_copy(
        update={
            "objects": [floor, *scene.objects[1:]],
            "materials": scene.materials | textured,
            "environment": EnvironmentMap(path="sky.exr"),
        }
    )
    stored = portable_scene(reads_files, {"ball": BALL_BOUNDS})
    assert stored.spec is None
    for field in ("objects[0].shape.path", "materials.red.reflectance.path", "environment.path"):
        assert field in stored.reason
    # a replaced object may read its mesh from a file: the artifact does not need it
    mesh_ball = scene.objects[-1].model_copy(update={"shape": MeshShape(path="ball.obj")})
    with_mesh = scene.model_copy(update={"objects": [*scene.objects[:-1], mesh_ball]})
    assert portable_scene(with_mesh, {}).spec is None
    assert portable_scene(with_mesh, {"ball": BALL_BOUNDS}).spec is not None


def scene_with_files(folder):
    """`instanced_scene` reading files from `folder` as an upload does: the floor from an OBJ in a
    subfolder, a box from a glTF with external buffers, a texture, an EXR sky; and a file it never reads."""
    (folder / "meshes").mkdir(parents=True)
    floor = trimesh.Trimesh([[-1, -1, -1], [1, -1, -1], [1, -1, 1], [-1, -1, 1]], [[0, 2, 1], [0, 3, 2]])
    (folder / "meshes" / "floor.obj").write_text(floor.export(file_type="obj"))
    (folder / "props").mkdir()
    box = trimesh.Scene(trimesh.creation.box(extents=(0.3, 0.3, 0.3))).export(file_type="gltf")
    for name, data in box.items():
        (folder / "props" / name).write_bytes(data)
    write_png(folder / "red.png", np.full((4, 4, 3), 0.4, np.float32))
    write_exr(folder / "sky.exr", np.full((8, 16, 3), 0.5, np.float32))
    (folder / "notes.txt").write_text("not part of the scene")
    scene = instanced_scene()
    objects = [
        scene.objects[0].model_copy(update={"shape": MeshShape(path="meshes/floor.obj")}),
        *scene.objects[1:],
        SceneObject(name="box", shape=MeshShape(path="props/model.gltf"), material="red"),
    ]
    materials = scene.materials | {"red": Diffuse(reflectance=ImageTexture(path="red.png"))}
    update = {"objects": objects, "materials": materials, "environment": EnvironmentMap(path="sky.exr")}
    return scene.model_copy(update=update)


KEPT = {"meshes/floor.obj", "props/model.gltf", "props/gltf_buffer_0.bin", "props/gltf_buffer_1.bin"}
KEPT |= {"red.png", "sky.exr"}


def test_an_artifact_keeps_the_files_its_scene_reads_and_renders_without_the_jobs_folder(
    tmp_path, monkeypatch
):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    job, artifact = tmp_path / "job", tmp_path / "artifact"
    spec = scene_with_files(job)
    before = compile_scene(spec, job)
    stored = portable_scene(spec, {}, job)
    assert stored.spec is not None and set(stored.files) == KEPT and stored.base == "."
    assert set(save_scene(artifact, stored)) == {"scene.json", *(f"scene/{name}" for name in KEPT)}
    shutil.rmtree(job)
    loaded = load_scene(artifact)
    shutil.rmtree(artifact)  # the inference service's download folder goes once the model is loaded
    after = loaded.compiled()
    np.testing.assert_array_equal(after.positions, before.positions)
    image = render(PathTracer(after), RenderSettings(spp=1, width=8, height=6, threads=1)).image
    assert np.isfinite(image).all() and image.mean() > 0  # the texture and the sky load at render time
    # an object the model replaces does not need its files
    assert not {name for name in portable_scene(spec, {"box": BALL_BOUNDS}, job).files if "props" in name}


def test_kept_files_are_verified_and_a_file_that_cannot_be_kept_is_the_reason(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    job, artifact = tmp_path / "job", tmp_path / "artifact"
    spec = scene_with_files(job)
    save_scene(artifact, portable_scene(spec, {}, job))
    (artifact / "scene" / "red.png").write_bytes(b"tampered")
    with pytest.raises(OSError, match="not the scene's sha256:"):
        load_scene(artifact)
    absolute = spec.model_copy(update={"environment": EnvironmentMap(path=str(job / "sky.exr"))})
    assert "environment.path names an absolute path" in portable_scene(absolute, {}, job).reason
    missing = spec.model_copy(update={"environment": EnvironmentMap(path="gone.exr")})
    assert "gone.exr, which is not in the job's folder" in portable_scene(missing, {}, job).reason
    assert portable_scene(missing, {}, job).spec is None


def test_stored_scenes_round_trip_and_old_artifacts_have_none(tmp_path):
    stored = portable_scene(instanced_scene(), {"ball": BALL_BOUNDS})
    files = save_scene(tmp_path, stored)
    assert set(files) == {"scene.json"}
    assert load_scene(tmp_path) == stored
    refused = StoredScene(None, reason="reads files")
    save_scene(tmp_path, refused)
    assert load_scene(tmp_path) == refused
    assert "before artifacts kept their scene" in load_scene(tmp_path / "old").reason


def test_the_neutral_scene_frames_its_objects_under_a_grey_sky():
    ball = SceneObject(name="ball", shape=SphereShape(radius=0.3), material="m")
    compiled = compile_scene(neutral_scene([ball], {"m": Diffuse()}))
    assert compiled.spec.environment.radiance == (NEUTRAL_RADIANCE,) * 3
    camera = framing_camera(BALL_BOUNDS)
    distance = np.linalg.norm(np.subtract(camera.position, camera.target))
    half_angle = np.degrees(np.arcsin(np.linalg.norm(BALL_BOUNDS[1]) / distance))
    assert half_angle < camera.fov / 2 and np.allclose(camera.target, 0)


def test_a_cameras_given_fields_override_the_views_own():
    base = Camera(position=(0, 1, 5), target=(0, 1, 0), fov=30, width=64, height=48)
    moved = CameraParams(position=(3, 1, 0), width=8).over(base)
    assert (
        moved.position == (3, 1, 0) and moved.target == (0, 1, 0) and (moved.width, moved.height) == (8, 48)
    )
    assert moved.fov == 30
    with pytest.raises(ValueError, match=r"^params\.camera: .*coincides"):
        CameraParams(position=(0, 1, 0)).over(base)
    params = ViewRender(spp=16)
    assert params.settings(moved).spp == 16 and params.settings(moved).width == 8
    large = CameraParams(width=4096, height=4096).over(base)
    with pytest.raises(ValueError, match=r"^params\.spp: 4096x4096 at 2 spp is .* samples"):
        ViewRender(spp=2 * MAX_SAMPLES // 4096**2).settings(large)
