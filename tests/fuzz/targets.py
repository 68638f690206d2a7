"""atheris fuzz targets for the parsers that read what an attacker sends: scene files, upload archives and
the inference wire format. Each target accepts only the parser's own error (a 4xx); anything else is a
crash, which atheris reports with the input that caused it.

    python -m tests.fuzz.targets scene -max_total_time=60     # any libFuzzer flag after the target
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
from pathlib import Path

import atheris

with atheris.instrument_imports(include=["services", "workers"]):
    from services.artifacts.archives import extract_archive
    from services.artifacts.staging import Staging, UploadError, UploadLimits
    from services.inference.errors import MalformedBody
    from services.inference.wire import decode_binary
    from workers.scene.errors import SceneError
    from workers.scene.io import load_scene

WORK = Path(tempfile.mkdtemp(prefix="nbake-fuzz-"))
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


TARGETS = {"scene": scene, "archive": archive, "wire": wire}
SEEDS = {
    "scene": [
        b"\x00materials: {m: {type: diffuse}}\nobjects: [{name: a, shape: {type: box}, material: m}]\n"
    ],
    "archive": [],
    "wire": [b'{"params": {}, "arrays": {"x": {"dtype": "float32", "shape": [2, 3]}}}\n' + bytes(24)],
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
