"""Fuzz targets for the parsers that read what an attacker sends: every importer an upload reaches (scene
files in YAML/JSON, glTF/GLB and USD; the meshes and textures a scene names; zip and tar archives), the
inference wire format and the SSE `Last-Event-ID` header. Each target accepts only the parser's own error
(a 4xx); anything else is a crash. `tests/fuzz/__main__.py` runs one under atheris.

An upload goes through the server's own entry, `ingest_upload` (staging and its limits, archives, the
scene and every file it names parsed, checked and built), in this process. An upload target's input is
one file: its first byte picks the file's name, the rest is its content. `SEEDS` start each corpus with
every hostile input of issue 50's table and a valid file of each kind.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from PIL import Image

from services.artifacts.store import BlobStore
from services.artifacts.uploads import UploadError, UploadLimits, ingest_upload
from services.inference.errors import MalformedBody
from services.inference.wire import decode_binary
from tests.support import hostile_inputs as hostile
from tests.support import usd_files
from tests.support.archives import tarred, zipped
from workers.scene.format.errors import SceneError
from workers.scene.geometry.budget import MAX_SCENE_INSTANCES

WORK_ENV = "NBAKE_FUZZ_DIR"  # a folder the caller owns and removes (libFuzzer exits without clean-up)
LIMITS = UploadLimits(max_total_bytes=1 << 20, max_files=20, max_file_bytes=1 << 20)
# An upload's errors the API answers with a 4xx. The server parses in child processes with an address-space
# ceiling and answers a MemoryError there 422 (services/geometry.py); `python -m tests.fuzz` sets such a
# ceiling, and growth below it is libFuzzer's -rss_limit_mb to catch.
USER_ERRORS = (UploadError, SceneError, MemoryError)


def upload(files: hostile.Files) -> None:
    """`files` uploaded as the server takes them, in this process; only the upload's own errors pass."""
    with tempfile.TemporaryDirectory(dir=os.environ.get(WORK_ENV)) as work:
        parts = [(name, io.BytesIO(data)) for name, data in files]
        with contextlib.suppress(*USER_ERRORS):
            ingest_upload(parts, BlobStore(f"{work}/blobs"), LIMITS, work_dir=Path(work))


@dataclass(frozen=True)
class UploadTarget:
    """Uploads one fuzzed file: an input's first byte picks its name from `names`, the rest is its content.
    `scene`, given that name, writes the scene file uploaded beside it (one that names it)."""

    names: tuple[str, ...]
    scene: Callable[[str], str] | None = None

    def __call__(self, data: bytes) -> None:
        name = self.names[data[0] % len(self.names)] if data else self.names[0]
        beside = [] if self.scene is None else [("scene.yaml", self.scene(name).encode())]
        upload([*beside, (name, data[1:])])

    def seed(self, files: hostile.Files) -> bytes:
        """The input that uploads the file of `files` with one of this target's suffixes (under this target's
        name for that suffix: the target brings its own scene)."""
        for name, content in files:
            for index, own in enumerate(self.names):
                if "".join(PurePosixPath(name).suffixes[-2:]) == "".join(PurePosixPath(own).suffixes[-2:]):
                    return bytes([index]) + content
        raise ValueError(f"none of {[name for name, _ in files]} is a file of {self.names}")


scene = UploadTarget(("scene.yaml", "scene.json"))
gltf = UploadTarget(("scene.gltf", "scene.glb"))
usd = UploadTarget(("scene.usda",))
usdc = UploadTarget(("scene.usdc",))  # usd-core's crate reader: see tests/unit/test_fuzz_parsers.py
mesh = UploadTarget(("mesh.obj", "mesh.ply", "mesh.stl"), hostile.mesh_scene)
texture = UploadTarget(("texture.png", "texture.jpg", "texture.exr"), hostile.textured_scene)
archive = UploadTarget(("upload.zip", "upload.tar", "upload.tar.gz"))


def wire(data: bytes) -> None:
    with contextlib.suppress(MalformedBody):
        decode_binary(data)


@functools.cache
def _job_server():
    """A job server (API only, SQLite in a work folder) in process, and a job that ended (cancelled while
    queued), whose event stream therefore ends: (client, job id)."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.api.settings import ServiceSettings

    work = Path(tempfile.mkdtemp(prefix="server-", dir=os.environ.get(WORK_ENV)))
    settings = ServiceSettings(data_dir=work, tokens="fuzz-token:admin", scheduling=False)
    client = TestClient(create_app(settings), headers={"Authorization": "Bearer fuzz-token"})
    client.__enter__()  # runs the app's startup (migrations, tokens); the process exits without teardown
    job = client.post("/v1/jobs", json={"kind": "render", "scene": "cornell_box", "preset": "quick"}).json()
    client.post(f"/v1/jobs/{job['id']}:cancel")
    return client, job["id"]


FIELD_VALUE = re.compile(rb"[\t\x20-\x7e\x80-\xff]*")  # what an HTTP parser hands on (RFC 9110 5.5)
EVENT_ID = re.compile(rb"^id: (\d+)$", re.MULTILINE)


def last_event_id(data: bytes) -> None:
    """Any header value a client can send: a 4xx, or the events after it in order (never a 5xx)."""
    value = data.strip(b" \t")
    if not FIELD_VALUE.fullmatch(value):
        return
    client, job_id = _job_server()
    response = client.get(f"/v1/jobs/{job_id}/events", headers={"Last-Event-ID": value})
    if response.status_code >= 500:
        raise RuntimeError(f"Last-Event-ID {value!r}: {response.status_code} {response.text[:300]}")
    if response.status_code == 200:
        try:
            after = int(value)
        except ValueError:  # a form the API reads as a number and Python's int() does not: order only
            after = -1
        sent = [int(seq) for seq in EVENT_ID.findall(response.content)]
        if sent != sorted(sent) or any(seq <= after for seq in sent):
            raise RuntimeError(f"Last-Event-ID {value!r}: events {sent} are not those after it, in order")


TARGETS: dict[str, Callable[[bytes], None]] = {
    "scene": scene,
    "gltf": gltf,
    "usd": usd,
    "usdc": usdc,
    "mesh": mesh,
    "texture": texture,
    "archive": archive,
    "wire": wire,
    "last_event_id": last_event_id,
}

_BOX_SCENE = (
    "materials: {m: {type: diffuse}}\nobjects: [{name: a, shape: {type: box}, material: m}]\n" + hostile.LIGHT
)
_TRIANGLE_OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
_TRIANGLE_PLY = b"""ply
format ascii 1.0
element vertex 3
property float x
property float y
property float z
element face 1
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
0 1 0
3 0 1 2
"""
_TRIANGLE_STL = b"""solid t
facet normal 0 0 1
outer loop
vertex 0 0 0
vertex 1 0 0
vertex 0 1 0
endloop
endfacet
endsolid t
"""


def _bytes_of(parts: list[tuple[str, io.BytesIO]]) -> hostile.Files:
    return [(name, stream.getvalue()) for name, stream in parts]


def _patched(data: bytes, changes: dict[int, int]) -> bytes:
    """`data` with the byte at each offset of `changes` set to its value."""
    patched = bytearray(data)
    for at, value in changes.items():
        patched[at] = value
    return bytes(patched)


def _png(width: int, height: int) -> bytes:
    encoded = io.BytesIO()
    Image.new("RGB", (width, height), (200, 100, 50)).save(encoded, format="PNG")
    return encoded.getvalue()


def _seeds() -> dict[str, dict[str, bytes]]:
    """Each target's first corpus, by name: issue 50's hostile inputs, scaled down where only their size was
    hostile (a list of ones, an instancer just over its limit), a valid file of each kind, and the inputs
    fuzzing found crashing a parser (each fixed since)."""
    instancer = hostile.usd_point_instancer(MAX_SCENE_INSTANCES + 1)
    faceless = hostile.usd_mesh_without_faces()
    triangle = hostile.gltf_triangle()
    instancer_usdc = usd_files.usdc(hostile.usd_point_instancer(3)[0][1])
    return {
        "scene": {
            "box": scene.seed([("scene.yaml", _BOX_SCENE.encode())]),
            "list of ones": scene.seed(hostile.yaml_list(1000)),
            "alias bomb": scene.seed([("scene.yaml", hostile.YAML_ALIAS_BOMB.encode())]),
        },
        "gltf": {
            "triangle": gltf.seed([("scene.gltf", json.dumps(triangle).encode())]),
            "triangle glb": gltf.seed([("scene.glb", hostile.glb(triangle))]),
            "accessor bomb": gltf.seed(hostile.gltf_accessor_bomb()),
            "accessor bomb glb": gltf.seed(
                [("scene.glb", hostile.glb(json.loads(hostile.gltf_accessor_bomb()[0][1])))]
            ),
            **{name: gltf.seed(files) for name, files in hostile.gltf_variants().items()},
            "buffer view without byteLength": gltf.seed(hostile.gltf_view_without_length()),
            "data URI not ASCII": gltf.seed(hostile.gltf_data_uri_not_ascii()),
            "POSITION of VEC2": gltf.seed(hostile.gltf_positions_of_two_numbers()),
            "no vertex": gltf.seed(hostile.gltf_without_vertices()),
        },
        "usd": {
            "point instancer over the limit": usd.seed(instancer),
            "mesh without faces": usd.seed(faceless),
            "instancer of no prototype": usd.seed(hostile.usd_instancer_of_no_prototype()),
            "instancer without instances": usd.seed(hostile.usd_instancer_without_instances()),
            "bytes not UTF-8": usd.seed(hostile.usd_not_utf8()),
            "instancer with fewer positions": usd.seed(hostile.usd_instancer_with_fewer_positions()),
            "points of an unknown type": usd.seed(hostile.usd_points_of_unknown_type()),
            "protoIndices of an unknown type": usd.seed(hostile.usd_instancer_indices_of_unknown_type()),
        },
        "usdc": {
            "mesh without faces": usdc.seed([("scene.usdc", usd_files.usdc(faceless[0][1]))]),
            "point instancer": usdc.seed([("scene.usdc", instancer_usdc)]),
            # the same with bytes of its crate changed (fuzzing found them): a value usd-core cannot unpack,
            # and upAxis metadata of another type
            "value that cannot be unpacked": usdc.seed(
                [("scene.usdc", _patched(instancer_usdc, {699: 177}))]
            ),
            "upAxis of another type": usdc.seed(
                [("scene.usdc", _patched(instancer_usdc, {207: 4, 633: 26}))]
            ),
        },
        "mesh": {
            "obj": mesh.seed([("a.obj", _TRIANGLE_OBJ)]),
            "ply": mesh.seed([("a.ply", _TRIANGLE_PLY)]),
            "stl": mesh.seed([("a.stl", _TRIANGLE_STL)]),
            "obj vertex with two coordinates": mesh.seed(hostile.obj_vertex_with_two_coordinates()),
        },
        "texture": {
            "png": texture.seed([("a.png", _png(2, 2))]),
            "png declaring 10^10 pixels": texture.seed([("big.png", hostile.png_header(100_000, 100_000))]),
        },
        "archive": {
            "zip name flagged UTF-8": archive.seed(hostile.zip_with_bad_utf8_name()),
            "zip of a texture bomb": archive.seed(_bytes_of(zipped(dict(hostile.png_bomb_texture())))),
            "tar.gz of a faceless mesh": archive.seed(_bytes_of(tarred(dict(faceless)))),
            "zip compression method 99": archive.seed(hostile.zip_with_unknown_compression()),
            "zip corrupt bzip2": archive.seed(hostile.zip_with_corrupt_bzip2()),
            "tar.gz header cut short": archive.seed(hostile.tar_gz_header_cut_short()),
            "zip member without a name": archive.seed(hostile.zip_member_without_name()),
            "zip header before its start": archive.seed(hostile.zip_central_directory_past_its_place()),
        },
        "wire": {
            "2x3 floats": b'{"params": {}, "arrays": {"x": {"dtype": "float32", "shape": [2, 3]}}}\n'
            + bytes(24)
        },
        "last_event_id": {"0": b"0", "1": b"1", "int32 max": b"2147483647", "padded": b" 3 "},
    }


SEEDS = _seeds()
