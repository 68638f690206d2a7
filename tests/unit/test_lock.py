"""The locks in requirements/ are what installs, and they are fresh: every requirement of the
pyproject.toml files is met by its pin (`make lock` after editing one), the server's and the client's
locks agree with the developers' lock, torch stays out of them (its wheel differs by machine; the Makefile
and constraints.txt pin it), and this environment holds exactly the pinned versions."""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]
PIN = re.compile(r"^([A-Za-z0-9._-]+)==([^\s;]+)(?:\s*;\s*(.+))?$")


def pins(lock: str) -> dict[str, Version]:
    """Package -> pinned version of the lock's lines whose markers hold here."""
    found = {}
    for line in (ROOT / "requirements" / lock).read_text().splitlines():
        if match := PIN.match(line.strip()):
            name, version, marker = match.groups()
            if marker is None or Requirement(f"x; {marker}").marker.evaluate():
                found[canonicalize_name(name)] = Version(version)
    return found


def requirements(pyproject: str, extra: str | None = None) -> list[Requirement]:
    project = tomllib.loads((ROOT / pyproject).read_text())["project"]
    lines = project["dependencies"] + (project["optional-dependencies"][extra] if extra else [])
    return [r for r in map(Requirement, lines) if r.marker is None or r.marker.evaluate()]


LOCKS = {
    "dev.txt": requirements("pyproject.toml", "dev") + requirements("clients/python/pyproject.toml"),
    "server.txt": requirements("pyproject.toml") + requirements("clients/python/pyproject.toml"),
    "client.txt": requirements("clients/python/pyproject.toml"),
}


@pytest.mark.parametrize("lock", sorted(LOCKS))
def test_every_requirement_is_met_by_the_lock(lock):
    pinned = pins(lock)
    unmet = [
        f"{r} (locked: {pinned.get(canonicalize_name(r.name), 'absent')})"
        for r in LOCKS[lock]
        if r.name != "torch" and not r.specifier.contains(pinned.get(canonicalize_name(r.name), "0"), True)
    ]
    assert not unmet, f"requirements/{lock} is stale, run `make lock`: {unmet}"


@pytest.mark.parametrize("lock", ["server.txt", "client.txt"])
def test_the_narrower_locks_agree_with_the_developers_lock(lock):
    dev = pins("dev.txt")
    differ = {name: (str(v), str(dev.get(name))) for name, v in pins(lock).items() if dev.get(name) != v}
    assert not differ, f"requirements/{lock} disagrees with dev.txt (run `make lock`): {differ}"


def test_torch_is_pinned_outside_the_locks():
    assert all("torch" not in pins(lock) for lock in LOCKS)
    assert "torch==2.13.0" in (ROOT / "constraints.txt").read_text().split()


def test_this_environment_holds_the_locked_versions():
    installed = {canonicalize_name(d.metadata["Name"]): Version(d.version) for d in metadata.distributions()}
    wrong = {
        name: (str(version), str(installed.get(name)))
        for name, version in pins("dev.txt").items()
        if installed.get(name) != version
    }
    assert not wrong, f"installed versions differ from requirements/dev.txt (`make clean venv`): {wrong}"
