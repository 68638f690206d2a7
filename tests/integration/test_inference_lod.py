"""A `lod` artifact served by `nbake serve-inference`: first scattering events of rays at a chosen LoD and
the voxels' prefiltered throughput, equal to the kind's in-process `infer`; requests with and without
the optional `incident` input arriving together are answered separately, each correctly. Renders of the
asset at a LoD, in the scene the artifact keeps or alone, equal the in-process ones; the LoD follows the
camera's distance when none is asked for; an artifact without its scene renders only alone."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.wire import decode_binary
from tests.integration.test_inference_server import (
    SMALL_VIEW,
    Server,
    binary_query,
    exr_pixels,
    frame_ms,
    install_tokens,
    rendered_in_process,
    run_and_publish,
    start_server,
)
from workers.models.lod.infer import LodQuery, LodRender
from workers.models.registry import get_inference
from workers.scene.format.spec import Camera
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.portable import StoredScene, load_scene, save_scene


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[Server]:
    data_dir = tmp_path_factory.mktemp("inference-lod")
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    scene = get_builtin("menger_sponge")
    scene = scene.model_copy(update={"camera": scene.camera.model_copy(update={"width": 32, "height": 32})})
    lod = run_and_publish(
        store, tmp_path_factory.mktemp("jobs"), "lod", scene, {"samplers": 0, "train": {"steps": 20}}, seed=5
    )
    install_tokens(data_dir)
    running = start_server(data_dir, ["--max-wait-ms", "50"], lod)
    try:
        yield running
    finally:
        running.stop()


def rays(n: int, seed: int) -> dict[str, np.ndarray]:
    """Rays from around the sponge (centre (0, 0.5, 0), side 1) towards it, and incident directions."""
    rng = np.random.default_rng(seed)
    targets = np.array([0.0, 0.5, 0.0]) + rng.uniform(-0.6, 0.6, (n, 3))
    origins = targets + rng.normal(size=(n, 3)) * 3
    return {"origins": origins, "directions": targets - origins, "incident": rng.normal(size=(n, 3))}


def in_process(server: Server, arrays: dict, level: int) -> dict[str, np.ndarray]:
    model = server.lsnif.in_process()  # the fixture's only artifact sits in the first slot
    return model.answer("query", LodQuery(level=level), arrays).arrays


def test_lod_queries_equal_in_process_inference_at_every_level(server):
    arrays = rays(2000, seed=1)
    with server.client() as client:
        for level in range(3):
            reference = in_process(server, arrays, level)
            assert 0.2 < reference["hit"].mean() < 1.0
            response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": level})
            assert response.status_code == 200, response.text
            answer = decode_binary(response.content)[1]
            assert set(answer) == {"hit", "distance", "voxel", "throughput"}
            for name, value in reference.items():
                np.testing.assert_array_equal(answer[name], value, err_msg=name)
            hit = answer["hit"]
            assert np.all(answer["voxel"][hit] >= 0) and np.all(answer["voxel"][~hit] == -1)
            assert np.all(answer["throughput"] >= 0) and np.all(answer["throughput"][~hit] == 0)
        response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": 7})
        assert response.status_code == 422 and "params.level" in response.text


def test_requests_with_and_without_optional_inputs_are_not_merged(server):
    def ask(seed: int) -> tuple[dict, dict]:
        arrays = rays(300, seed)
        if seed % 2:
            del arrays["incident"]
        with server.client() as client:
            response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": 1})
            assert response.status_code == 200, response.text
            return decode_binary(response.content)[1], in_process(server, arrays, 1)

    with ThreadPoolExecutor(8) as pool:
        for answer, reference in pool.map(ask, range(16)):
            assert set(answer) == set(reference)
            for name, value in reference.items():
                np.testing.assert_array_equal(answer[name], value, err_msg=name)


def test_lod_renders_a_chosen_lod_in_its_scene_or_alone(server):
    artifact = server.lsnif  # the fixture's lod artifact
    views = [
        SMALL_VIEW | {"level": 0},
        SMALL_VIEW | {"level": 2},
        SMALL_VIEW | {"level": 2, "background": "neutral"},
    ]
    images = []
    with server.client() as client:
        for params in views:
            response = client.post(f"/v1/artifacts/{artifact.artifact_id}:render", json={"params": params})
            assert response.status_code == 200, response.text
            assert frame_ms(response) > 0
            images.append(exr_pixels(response.content, server.data_dir))
            np.testing.assert_array_equal(
                images[-1], rendered_in_process(artifact, params), err_msg=str(params)
            )
        too_fine = client.post(
            f"/v1/artifacts/{artifact.artifact_id}:render", json={"params": SMALL_VIEW | {"level": 3}}
        )
        assert too_fine.status_code == 422 and too_fine.json()["field"] == "params.level"
    assert not np.array_equal(images[0], images[1]) and not np.array_equal(images[1], images[2])
    assert images[2][0, 0] == pytest.approx([0.5, 0.5, 0.5])  # the grey sky behind the asset alone


def test_the_lod_follows_the_camera_distance(server):
    """A voxel of the chosen LoD is about a pixel: 32^3 near, 8^3 far away (as `plan` picks LoDs)."""
    model = server.lsnif.in_process()
    centre = model.bounds.mean(0)
    away = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])

    def camera(distance: float, height: int) -> dict:
        return {"position": tuple(centre + distance * away), "target": tuple(centre), "height": height}

    assert [model.level_for(Camera(**camera(d, 32))) for d in (0.5, 4.0, 60.0)] == [0, 1, 2]
    assert model.level_for(Camera(**camera(4.0, 8))) == 2  # fewer, larger pixels
    near = {"camera": camera(0.5, 16) | {"width": 16}, "spp": 1}
    answer = model.answer("render", LodRender.model_validate(near), {})
    assert answer.meta["level"] == model.level_for(Camera(**camera(0.5, 16))) == 0


def test_an_artifact_without_its_scene_renders_the_asset_alone(server, tmp_path):
    folder = tmp_path / "lod"
    shutil.copytree(server.lsnif.folder, folder)
    reason = "the scene reads files from the job's folder (objects[0].shape.path)"
    save_scene(folder, StoredScene(None, reason=reason))
    assert load_scene(folder).spec is None
    model = get_inference("lod").load(folder, "cpu")
    with pytest.raises(
        ValueError, match=r"params.background: .*objects\[0\]\.shape\.path.*background: neutral"
    ):
        model.answer("render", LodRender.model_validate(SMALL_VIEW), {})
    alone = model.answer("render", LodRender.model_validate(SMALL_VIEW | {"background": "neutral"}), {})
    expected = rendered_in_process(server.lsnif, SMALL_VIEW | {"background": "neutral"})
    np.testing.assert_array_equal(alone.arrays["image"], expected)
