"""The checked-in gRPC stubs are what `make proto` generates from proto/, and the protos pass `buf lint`
(STANDARD) when buf is installed.

Generated code carries the generator's versions (`GRPC_GENERATED_VERSION`, protobuf's runtime check): the
lock pins the generator, but the comparison leaves those stamps out, so that what it checks is the code
the protos make; the stamps are checked against what the client package promises its users instead (a
stub stamped newer than the client's `grpcio>=` refuses to import on a user's older grpcio)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]
CHECKED_IN = ROOT / "clients/python/neuralbake/v1"

GRPC_STAMP = re.compile(r"^GRPC_GENERATED_VERSION = '([^']+)'$", re.M)
PROTOBUF_STAMP = re.compile(r"^# Protobuf Python Version: (\S+)$", re.M)
PROTOBUF_CHECK = re.compile(r"ValidateProtobufRuntimeVersion\(\s*_runtime_version\.Domain\.PUBLIC,[^)]*\)")


def without_version_stamps(text: str) -> str:
    text = GRPC_STAMP.sub("GRPC_GENERATED_VERSION = ...", text)
    text = PROTOBUF_STAMP.sub("# Protobuf Python Version: ...", text)
    return PROTOBUF_CHECK.sub("ValidateProtobufRuntimeVersion(...)", text)


def client_minimum(package: str) -> Version:
    """The lowest version of `package` that the client package's requirements admit."""
    project = tomllib.loads((ROOT / "clients/python/pyproject.toml").read_text())["project"]
    for line in project["dependencies"]:
        requirement = Requirement(line)
        if requirement.name == package:
            (lower,) = [Version(s.version) for s in requirement.specifier if s.operator in (">=", "==")]
            return lower
    raise LookupError(f"the client package does not require {package}")


def test_checked_in_stubs_match_a_fresh_generation(tmp_path):
    # -o: treat the venv as up to date, so the test never reinstalls it
    done = subprocess.run(
        ["make", "-s", "-o", ".venv/.installed", "proto", f"PROTO_OUT={tmp_path}", f"PY={sys.executable}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    fresh = tmp_path / "neuralbake/v1"
    generated = sorted(p.name for p in fresh.glob("*_pb2*.py"))
    assert generated == sorted(p.name for p in CHECKED_IN.glob("*_pb2*.py")), "run `make proto`"
    stale = [
        name
        for name in generated
        if without_version_stamps((fresh / name).read_text())
        != without_version_stamps((CHECKED_IN / name).read_text())
    ]
    assert not stale, f"stale stubs {stale}: run `make proto`"


def test_the_stubs_import_on_the_oldest_runtime_the_client_admits():
    stubs = sorted(CHECKED_IN.glob("*_pb2*.py"))
    grpc_stamps = {Version(v) for p in stubs for v in GRPC_STAMP.findall(p.read_text())}
    protobuf_stamps = {Version(v) for p in stubs for v in PROTOBUF_STAMP.findall(p.read_text())}
    assert grpc_stamps and protobuf_stamps, "the generated stubs carry no version stamps: update this test"
    assert max(grpc_stamps) <= client_minimum("grpcio"), "raise grpcio>= in clients/python/pyproject.toml"
    assert max(protobuf_stamps) <= client_minimum("protobuf"), "raise protobuf>= in the client's pyproject"


def test_protos_pass_buf_lint():
    buf = shutil.which("buf", path=str(Path(sys.executable).parent))
    if buf is None:
        pytest.skip("buf is not installed (pip install buf-bin)")
    done = subprocess.run([buf, "lint", "proto"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
