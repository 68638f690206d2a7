"""The scene an artifact keeps (`workers.scene.portable`) and the parameters of a path-traced `:render`
(`workers.runtime.view_render`): stand-ins keep their objects' placements and enclose their bounds, a
scene that reads files is refused with the fields at fault, and a camera's given fields override the
view's own."""

from __future__ import annotations

import numpy as np
import pytest

from tests.unit.test_lsnif_model import instanced_scene
from workers.runtime.view_render import MAX_SAMPLES, CameraParams, ViewRender
from workers.scene.compile import compile_scene
from workers.scene.portable import (
    NEUTRAL_RADIANCE,
    StoredScene,
    framing_camera,
    load_scene,
    neutral_scene,
    portable_scene,
    save_scene,
)
from workers.scene.spec import (
    Camera,
    Diffuse,
    EnvironmentMap,
    ImageTexture,
    MeshShape,
    SceneObject,
    SphereShape,
)

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
