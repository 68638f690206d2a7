"""The inference service as users reach it: `nbake serve-inference` in its own process on free ports,
serving artifacts that real `lsnif` and `render` jobs produced and published into the store of its data
dir, with tokens in the job database as `nbake serve` leaves them. Answers are compared with the kinds'
`infer` run in this process on the same artifact files."""

from __future__ import annotations

import base64
import functools
import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import grpc
import httpx
import numpy as np
import pytest
from neuralbake.v1 import inference_pb2, inference_pb2_grpc

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.wire import OCTET_STREAM, decode_binary, encode_binary
from services.jobs.db import Database
from services.jobs.tokens import DatabaseTokens
from tests.integration.test_api_headers import assert_security_headers
from tests.integration.test_api_server import NBAKE, TOKENS
from tests.support.jobs import run_kind_job
from tests.support.ports import free_port
from tests.unit.test_lsnif_model import instanced_scene
from workers.models.registry import get_inference
from workers.scene.generators.builtin import BUILTIN_SCENES
from workers.scene.importers.image_io import read_exr

START_TIMEOUT_S = 60
RAY_OUTPUTS = ("hit", "distance", "normal", "albedo", "material", "object")


@dataclass
class Artifact:
    artifact_id: str
    folder: Path
    kind: str

    def in_process(self):
        """The kind's own `infer` on the job's output files: what the server must answer."""
        return _in_process(self.kind, self.folder)


@functools.cache
def _in_process(kind: str, folder: Path):
    return get_inference(kind).load(folder, "cpu")


def run_and_publish(store: ArtifactStore, work: Path, kind_name: str, scene, overrides: dict, seed: int):
    spec, outcome = run_kind_job(kind_name, scene, work / f"{kind_name}-{seed}", overrides, seed=seed)
    return publish(store, kind_name, spec, outcome)


def publish(store: ArtifactStore, kind_name: str, spec, outcome) -> Artifact:
    """A succeeded job's files, published into `store` as the job service does."""
    assert outcome.state == "succeeded", outcome.error
    files = {name: (path, outcome.media_types.get(name, "")) for name, path in outcome.files.items()}
    manifest = store.publish(
        files,
        kind=kind_name,
        job_id=spec.job_id,
        scene_hash="sha256:" + "1" * 64,
        config=spec.config,
        code_version="test",
        metrics=outcome.metrics,
    )
    return Artifact(manifest.artifact_id, Path(spec.output_dir), kind_name)


@dataclass
class Server:
    process: subprocess.Popen
    url: str
    grpc_target: str
    data_dir: Path
    lsnif: Artifact | None = None
    render: Artifact | None = None
    corrupted: Artifact | None = None

    def client(self, scope: str | None = "read") -> httpx.Client:
        headers = {"Authorization": f"Bearer {TOKENS[scope]}"} if scope else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=120)

    def metric(self, name: str, **labels: str) -> float:
        text = httpx.get(f"{self.url}/metrics", timeout=30).text
        wanted = [f'{k}="{v}"' for k, v in labels.items()]
        return sum(
            float(line.rsplit(" ", 1)[1])
            for line in text.splitlines()
            if line.startswith(name) and all(w in line for w in wanted)
        )

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)  # the group this test started, nothing else
                self.process.wait(30)


def install_tokens(data_dir: Path) -> None:
    """What `nbake serve` leaves in its data dir: a migrated job database holding the tokens."""
    db = Database(f"sqlite:///{data_dir / 'jobs.db'}")
    db.migrate()
    DatabaseTokens(db).store_configured({token: scope for scope, token in TOKENS.items()})
    db.dispose()


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[Server]:
    data_dir = tmp_path_factory.mktemp("inference")
    work = tmp_path_factory.mktemp("jobs")
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    lsnif = run_and_publish(
        store, work, "lsnif", instanced_scene(), {"min_triangles": 1000, "train": {"steps": 60}}, seed=7
    )
    render_overrides = {"samplers": 0, "width": 32, "height": 24, "spp": 4}
    cornell = BUILTIN_SCENES["cornell_box"]()
    render = run_and_publish(store, work, "render", cornell, render_overrides, seed=1)
    corrupted = run_and_publish(store, work, "render", cornell, render_overrides, seed=2)
    image = store.file(corrupted.artifact_id, "image.exr")
    store.blobs.local_path(image.digest).write_bytes(b"not the image any more")

    install_tokens(data_dir)

    # A budget that holds the lsnif model or the render model, not both: loading one evicts the other.
    budget = lsnif.in_process().nbytes + render.in_process().nbytes - 1
    options = ["--memory-bytes", str(budget), "--max-wait-ms", "20", "--max-rows", "20000"]
    running = start_server(data_dir, options, lsnif, render, corrupted)
    try:
        yield running
    finally:
        running.stop()


def start_server(data_dir: Path, options: list[str], *artifacts: Artifact) -> Server:
    """`nbake serve-inference` on free ports over `data_dir`, once it reports ready."""
    http_port, grpc_port = free_port(), free_port()
    command = [NBAKE, "serve-inference", "--port", str(http_port), "--grpc-port", str(grpc_port)]
    command += ["--data-dir", str(data_dir), "--device", "cpu", "--log-level", "warning", *options]
    log = (data_dir / "serve-inference.log").open("wb")
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    running = Server(process, f"http://127.0.0.1:{http_port}", f"127.0.0.1:{grpc_port}", data_dir, *artifacts)
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if process.poll() is not None:
            raise RuntimeError((data_dir / "serve-inference.log").read_text()[-3000:])
        try:
            if httpx.get(f"{running.url}/readyz", timeout=5).status_code == 200:
                return running
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline:
            running.stop()
            raise RuntimeError("nbake serve-inference did not become ready")
        time.sleep(0.2)


def aimed_rays(artifact: Artifact, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """World-space rays from around the trained instances towards them: most hit, some miss."""
    model = artifact.in_process()
    centers = np.array([i.world_bounds.mean(0) for i in model.intersector.instances])
    rng = np.random.default_rng(seed)
    targets = centers[rng.integers(len(centers), size=n)] + rng.normal(scale=0.15, size=(n, 3))
    origins = targets + rng.normal(size=(n, 3)) * 2
    return origins, targets - origins


def expected(artifact: Artifact, origins, directions) -> dict[str, np.ndarray]:
    model = artifact.in_process()
    params = get_inference("lsnif").operations["query"].params()
    return model.answer("query", params, {"origins": origins, "directions": directions}).arrays


def binary_query(client: httpx.Client, artifact_id: str, arrays: dict, params: dict | None = None):
    body = encode_binary({"params": params or {}}, arrays)
    response = client.post(
        f"/v1/artifacts/{artifact_id}:query", content=body, headers={"Content-Type": OCTET_STREAM}
    )
    return response


def assert_same(answer: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> None:
    assert set(answer) == set(RAY_OUTPUTS)
    for name in RAY_OUTPUTS:
        assert answer[name].dtype == reference[name].dtype, name
        np.testing.assert_array_equal(answer[name], reference[name], err_msg=name)


# ---------------------------------------------------------------------------------------------- lsnif


def test_lsnif_answers_equal_in_process_inference_over_binary_json_and_grpc(server):
    origins, directions = aimed_rays(server.lsnif, 3000, seed=1)
    reference = expected(server.lsnif, origins, directions)
    assert 0.2 < reference["hit"].mean() < 1.0  # a trained model: rays that hit and rays that miss
    with server.client() as client:
        response = binary_query(
            client, server.lsnif.artifact_id, {"origins": origins, "directions": directions}
        )
        assert response.status_code == 200, response.text
        assert response.headers["content-type"] == OCTET_STREAM
        head_and_arrays = decode_binary(response.content)
        assert_same(head_and_arrays[1], reference)

        small = {
            name: {
                "dtype": "float32",
                "shape": [50, 3],
                "data": base64.b64encode(a[:50].astype("<f4").tobytes()).decode(),
            }
            for name, a in (("origins", origins), ("directions", directions))
        }
        response = client.post(f"/v1/artifacts/{server.lsnif.artifact_id}:query", json={"arrays": small})
        assert response.status_code == 200, response.text
        body = response.json()
        assert body["kind"] == "lsnif" and body["meta"] == {"materials": ["white"], "objects": ["ball"]}
        hit = np.frombuffer(base64.b64decode(body["arrays"]["hit"]["data"]), bool)
        reference32 = expected(
            server.lsnif, origins[:50].astype(np.float32), directions[:50].astype(np.float32)
        )
        np.testing.assert_array_equal(hit, reference32["hit"])

    with grpc.insecure_channel(server.grpc_target) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        request = inference_pb2.QueryRequest(
            artifact_id=server.lsnif.artifact_id,
            arrays=[
                inference_pb2.Array(name=name, dtype="float64", shape=list(a.shape), data=a.tobytes())
                for name, a in (("origins", origins), ("directions", directions))
            ],
        )
        reply = stub.Query(request, metadata=(("authorization", f"Bearer {TOKENS['read']}"),), timeout=60)
        answer = {a.name: np.frombuffer(a.data, a.dtype).reshape(tuple(a.shape)) for a in reply.arrays}
        assert_same(answer, reference)
        with pytest.raises(grpc.RpcError) as refused:
            stub.Query(request, timeout=60)
        assert refused.value.code() == grpc.StatusCode.UNAUTHENTICATED


def test_concurrent_clients_get_their_own_answers_from_merged_batches(server):
    clients, per_client = 12, 3
    batches_before = server.metric("nbake_inference_batch_requests_count")
    merged_rows_before = server.metric("nbake_inference_batch_requests_sum")

    def one_client(number: int) -> None:
        with server.client() as client:
            for round_ in range(per_client):
                n = 200 + 37 * number + round_  # distinct sizes: a mixed-up split would not even fit
                origins, directions = aimed_rays(server.lsnif, n, seed=1000 * number + round_)
                response = binary_query(
                    client, server.lsnif.artifact_id, {"origins": origins, "directions": directions}
                )
                assert response.status_code == 200, response.text
                assert_same(decode_binary(response.content)[1], expected(server.lsnif, origins, directions))

    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(one_client, range(clients)))
    batches = server.metric("nbake_inference_batch_requests_count") - batches_before
    requests = server.metric("nbake_inference_batch_requests_sum") - merged_rows_before
    assert requests == clients * per_client
    assert batches < requests  # some calls served several requests at once


# ---------------------------------------------------------------------------------------------- render


def test_render_artifact_returns_its_stored_images(server):
    artifact_id = server.render.artifact_id
    stored = read_exr(server.render.folder / "image.exr")
    with server.client() as client:
        response = client.post(f"/v1/artifacts/{artifact_id}:render")
        assert response.status_code == 200, response.text
        assert response.headers["content-type"] == "image/x-exr"
        path = server.data_dir / "rendered.exr"
        path.write_bytes(response.content)
        np.testing.assert_array_equal(read_exr(path), stored)
        png = client.post(f"/v1/artifacts/{artifact_id}:render", headers={"Accept": "image/png"})
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG")

        pixels = np.array([[0, 0], [31, 23], [10, 5]], np.int64)
        response = binary_query(client, artifact_id, {"pixels": pixels}, {"layers": ["image", "depth"]})
        assert response.status_code == 200, response.text
        _, arrays = decode_binary(response.content)
        np.testing.assert_array_equal(arrays["image"], stored[pixels[:, 1], pixels[:, 0]])
        assert arrays["depth"].shape == (3, 1)
        whole = client.post(f"/v1/artifacts/{artifact_id}:query", json={"params": {"layers": ["albedo"]}})
        assert whole.status_code == 200 and whole.json()["arrays"]["albedo"]["shape"] == [24, 32, 3]

        layer = client.post(f"/v1/artifacts/{artifact_id}:render", json={"params": {"layer": "nope"}})
        assert layer.status_code == 422 and "albedo" in layer.json()["detail"]


def test_render_artifact_takes_a_camera_of_its_own_size_only(server):
    artifact_id = server.render.artifact_id
    stored = read_exr(server.render.folder / "image.exr")
    with server.client() as client:
        own = {"position": [0, 1, 4], "width": 32, "height": 24}
        response = client.post(f"/v1/artifacts/{artifact_id}:render", json={"params": {"camera": own}})
        assert response.status_code == 200, response.text
        np.testing.assert_array_equal(exr_pixels(response.content, server.data_dir), stored)
        assert frame_ms(response) >= 0
        other = {"camera": {"width": 64}}
        refused = client.post(f"/v1/artifacts/{artifact_id}:render", json={"params": other})
        assert refused.status_code == 422 and refused.json()["field"] == "params.camera.width"
        assert "one 32x24 view" in refused.json()["detail"]


# ---------------------------------------------------------------------------------------------- renders

SMALL_VIEW = {"camera": {"width": 16, "height": 12}, "spp": 2}


def frame_ms(response: httpx.Response) -> float:
    """The frame time of a render, from its `Server-Timing: frame;dur=<ms>` header."""
    name, _, duration = response.headers["server-timing"].partition(";dur=")
    assert name == "frame"
    return float(duration)


def exr_pixels(content: bytes, folder: Path) -> np.ndarray:
    path = folder / "answer.exr"
    path.write_bytes(content)
    return read_exr(path)


def rendered_in_process(artifact: Artifact, params: dict) -> np.ndarray:
    spec = get_inference(artifact.kind).operations["render"]
    return artifact.in_process().answer("render", spec.params.model_validate(params), {}).arrays["image"]


def test_lsnif_renders_its_objects_in_their_scene_or_alone(server):
    artifact_id = server.lsnif.artifact_id
    views = {
        "scene, camera rays on triangles": SMALL_VIEW,
        "scene, camera rays on lsnif": SMALL_VIEW | {"camera_rays": "lsnif"},
        "neutral background": SMALL_VIEW | {"background": "neutral"},
    }
    images = {}
    with server.client() as client:
        for name, params in views.items():
            response = client.post(f"/v1/artifacts/{artifact_id}:render", json={"params": params})
            assert response.status_code == 200, f"{name}: {response.text}"
            assert frame_ms(response) > 0
            images[name] = exr_pixels(response.content, server.data_dir)
            assert images[name].shape == (12, 16, 3)
            expected_image = rendered_in_process(server.lsnif, params)
            np.testing.assert_array_equal(images[name], expected_image, err_msg=name)
        for field, params in (
            ("params.camera_rays", views["neutral background"] | {"camera_rays": "triangles"}),
            ("params.camera", {"camera": {"position": [0, 0, 0], "target": [0, 0, 0]}}),
            ("params.spp", {"spp": 0}),
        ):
            response = client.post(f"/v1/artifacts/{artifact_id}:render", json={"params": params})
            assert response.status_code == 422 and response.json()["field"] == field, response.text
    scene, lsnif_primary, neutral = images.values()
    assert not np.array_equal(scene, lsnif_primary)  # the networks, not the triangles, drew the objects
    assert not np.array_equal(scene, neutral)


def test_render_frame_time_travels_as_grpc_metadata(server):
    request = inference_pb2.RenderRequest(artifact_id=server.lsnif.artifact_id, media_type="image/png")
    request.params.update(SMALL_VIEW | {"spp": 1})
    with grpc.insecure_channel(server.grpc_target) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        auth = (("authorization", f"Bearer {TOKENS['read']}"),)
        reply, call = stub.Render.with_call(request, metadata=auth, timeout=60)
    assert reply.media_type == "image/png" and reply.data.startswith(b"\x89PNG")
    timing = dict(call.trailing_metadata())["server-timing"]
    assert timing.startswith("frame;dur=") and float(timing.removeprefix("frame;dur=")) > 0


def test_a_non_finite_grpc_render_parameter_is_invalid_argument_naming_it(server):
    request = inference_pb2.RenderRequest(artifact_id=server.lsnif.artifact_id, media_type="image/png")
    request.params.update(SMALL_VIEW | {"camera": {"width": 16, "height": 12, "fov": float("inf")}})
    with grpc.insecure_channel(server.grpc_target) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        with pytest.raises(grpc.RpcError) as refused:
            stub.Render(request, metadata=(("authorization", f"Bearer {TOKENS['read']}"),), timeout=60)
    assert refused.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert refused.value.details().startswith("params.camera.fov: inf is not a finite number")


def test_responses_carry_the_security_headers(server):
    with server.client() as client:
        answers = [client.get("/v1/models"), client.post(f"/v1/artifacts/sha256:{'0' * 64}:query", json={})]
    for response in [*answers, httpx.get(f"{server.url}/docs"), httpx.get(f"{server.url}/openapi.json")]:
        assert_security_headers(response)


# ---------------------------------------------------------------------------------------------- cache


def test_models_are_evicted_least_recently_used_first_under_the_memory_budget(server):
    with server.client() as client:
        loaded = client.post(f"/v1/models/{server.lsnif.artifact_id}:load")
        assert loaded.status_code == 200 and loaded.json()["kind"] == "lsnif"
        evictions = server.metric("nbake_inference_cache_total", event="eviction")
        assert client.post(f"/v1/models/{server.render.artifact_id}:load").status_code == 200
        listed = [m["artifact_id"] for m in client.get("/v1/models").json()]
        assert listed == [server.render.artifact_id]  # the budget held one of the two
        assert server.metric("nbake_inference_cache_total", event="eviction") == evictions + 1
        origins, directions = aimed_rays(server.lsnif, 64, seed=5)
        again = binary_query(client, server.lsnif.artifact_id, {"origins": origins, "directions": directions})
        assert again.status_code == 200  # loaded again, evicting the render model
        assert [m["artifact_id"] for m in client.get("/v1/models").json()] == [server.lsnif.artifact_id]
    assert server.metric("nbake_inference_cache_total", event="hit") > 0


def test_a_corrupted_artifact_is_refused_and_not_loaded(server):
    with server.client() as client:
        response = client.post(f"/v1/models/{server.corrupted.artifact_id}:load")
        assert response.status_code == 409
        problem = response.json()
        assert response.headers["content-type"] == "application/problem+json"
        assert "'image.exr'" in problem["detail"] and "does not match its digest" in problem["detail"]
        assert server.corrupted.artifact_id not in [m["artifact_id"] for m in client.get("/v1/models").json()]
        query = client.post(f"/v1/artifacts/{server.corrupted.artifact_id}:render")
        assert query.status_code == 409


# ---------------------------------------------------------------------------------------------- errors


def test_bad_requests_get_clear_4xx_problems(server):
    lsnif = f"/v1/artifacts/{server.lsnif.artifact_id}:query"
    origins, directions = aimed_rays(server.lsnif, 10, seed=3)
    with server.client() as client:
        nan = origins.copy()
        nan[4, 1] = np.nan
        cases = [
            ({"origins": nan, "directions": directions}, 422, "arrays.origins", "NaN"),
            ({"origins": origins[:, :2], "directions": directions}, 422, "arrays.origins", "(N, 3)"),
            ({"origins": origins}, 422, "arrays.directions", "missing"),
            ({"origins": origins, "directions": directions[:5]}, 422, "arrays", "disagree"),
            (
                {"origins": origins, "directions": directions, "extra": origins},
                422,
                "arrays.extra",
                "unknown",
            ),
            (
                {"origins": origins.astype(np.complex64), "directions": directions},
                400,
                "arrays.origins",
                "dtype",
            ),
        ]
        for arrays, status, field, words in cases:
            response = binary_query(client, server.lsnif.artifact_id, arrays)
            assert response.status_code == status, (field, response.text)
            assert response.json()["field"] == field and words in response.json()["detail"], response.text
        many = np.zeros((20001, 3))
        too_many = binary_query(client, server.lsnif.artifact_id, {"origins": many, "directions": many + 1})
        assert too_many.status_code == 413 and "20000" in too_many.json()["detail"]
        garbage = client.post(lsnif, content=b"no header here", headers={"Content-Type": OCTET_STREAM})
        assert garbage.status_code == 400
        short = (
            json.dumps({"arrays": {"origins": {"dtype": "float64", "shape": [5, 3]}}}).encode() + b"\n1234"
        )
        truncated = client.post(lsnif, content=short, headers={"Content-Type": OCTET_STREAM})
        assert truncated.status_code == 400 and truncated.json()["field"] == "arrays.origins"
        bad_json = client.post(
            lsnif, json={"arrays": {"origins": {"dtype": "float64", "shape": [1, 3], "data": "@@"}}}
        )
        assert bad_json.status_code == 400 and bad_json.json()["field"] == "arrays.origins.data"
        accented = client.post(
            lsnif, json={"arrays": {"origins": {"dtype": "float64", "shape": [1, 3], "data": "AAé="}}}
        )
        assert accented.status_code == 400 and accented.json()["field"] == "arrays.origins.data"
        params = binary_query(
            client, server.lsnif.artifact_id, {"origins": origins, "directions": directions}, {"x": 1}
        )
        assert params.status_code == 422 and params.json()["field"] == "params.x"
        unknown = client.post(f"/v1/artifacts/sha256:{'0' * 64}:query", json={})
        assert unknown.status_code == 404 and "artifact not found" in unknown.json()["detail"]
        assert client.post("/v1/artifacts/not-a-digest:query", json={}).status_code == 404
    with server.client(scope=None) as anonymous:
        assert anonymous.get("/v1/models").status_code == 401


def test_open_endpoints_and_metrics(server):
    assert httpx.get(f"{server.url}/healthz").json() == {"status": "ok"}
    ready = httpx.get(f"{server.url}/readyz").json()
    assert ready["status"] == "ok" and ready["device"] == "cpu"
    text = httpx.get(f"{server.url}/metrics").text
    for name in (
        "nbake_inference_requests_total",
        "nbake_inference_latency_seconds_bucket",
        "nbake_inference_batch_rows_bucket",
        "nbake_inference_cache_total",
    ):
        assert name in text
    spec = httpx.get(f"{server.url}/openapi.json").json()
    content = spec["paths"]["/v1/artifacts/{artifact_id}:{operation}"]["post"]["requestBody"]["content"]
    assert {"application/json", OCTET_STREAM} <= set(content)
