"""atheris fuzz targets for the parsers that read what an attacker sends: scene files, upload archives,
the inference wire format and the SSE `Last-Event-ID` header. Each target accepts only the parser's own
error (a 4xx); anything else is a crash, which atheris reports with the input that caused it.

    python -m tests.fuzz.targets scene -max_total_time=60     # any libFuzzer flag after the target
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import sys
import tempfile
from pathlib import Path

import atheris

with atheris.instrument_imports(include=["services", "workers"]):
    from services.artifacts.archives import extract_archive
    from services.artifacts.staging import Staging, UploadError, UploadLimits
    from services.inference.errors import MalformedBody
    from services.inference.wire import decode_binary
    from workers.scene.format.errors import SceneError
    from workers.scene.portability.io import load_scene

# NBAKE_FUZZ_DIR: a folder the caller owns and removes (libFuzzer exits without Python's clean-up)
WORK = Path(tempfile.mkdtemp(prefix="nbake-fuzz-", dir=os.environ.get("NBAKE_FUZZ_DIR")))
LIMITS = UploadLimits(max_total_bytes=1 << 20, max_files=20, max_file_bytes=1 << 20)


def scene(data: bytes) -> None:
    provider = atheris.FuzzedDataProvider(data)
    suffix = ".json" if provider.ConsumeBool() else ".yaml"
    path = WORK / f"scene{suffix}"
    path.write_bytes(provider.ConsumeBytes(len(data)))
    with contextlib.suppress(SceneError):
        load_scene(path)


def archive(data: bytes) -> None:
    provider = atheris.FuzzedDataProvider(data)
    name = provider.PickValueInList(["upload.zip", "upload.tar", "upload.tar.gz"])
    path = WORK / name
    path.write_bytes(provider.ConsumeBytes(len(data)))
    with tempfile.TemporaryDirectory(dir=WORK) as folder, contextlib.suppress(UploadError):
        extract_archive(path, name, Staging(Path(folder), LIMITS))


def wire(data: bytes) -> None:
    with contextlib.suppress(MalformedBody):
        decode_binary(data)


@functools.cache
def _job_server():
    """A job server (API only, SQLite in the work folder) in process, and a job that ended (cancelled while
    queued), whose event stream therefore ends: (client, job id)."""
    with atheris.instrument_imports(include=["services"]):
        from fastapi.testclient import TestClient

        from services.api.app import create_app
        from services.api.settings import ServiceSettings
    settings = ServiceSettings(data_dir=WORK / "server", tokens="fuzz-token:admin", scheduling=False)
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


TARGETS = {"scene": scene, "archive": archive, "wire": wire, "last_event_id": last_event_id}
SEEDS = {
    "scene": [
        b"\x00materials: {m: {type: diffuse}}\nobjects: [{name: a, shape: {type: box}, material: m}]\n"
    ],
    "archive": [],
    "wire": [b'{"params": {}, "arrays": {"x": {"dtype": "float32", "shape": [2, 3]}}}\n' + bytes(24)],
    "last_event_id": [b"0", b"1", b"2147483647", b" 3 "],
}


def main() -> None:
    name = sys.argv[1]
    corpus = WORK / f"corpus-{name}"
    corpus.mkdir()
    for index, seed in enumerate(SEEDS[name]):
        (corpus / str(index)).write_bytes(seed)
    atheris.Setup([sys.argv[0], *sys.argv[2:], str(corpus)], TARGETS[name])
    atheris.Fuzz()


if __name__ == "__main__":
    main()
