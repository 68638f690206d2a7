"""File names inside an asset or artifact: relative POSIX paths that cannot leave their folder.

They come from users (multipart file names, archive members, scene fields) and later become
paths on disk, so anything that could escape (`..`, absolute paths, drive letters, backslashes,
control characters) is refused rather than repaired.
"""

from __future__ import annotations

import re

MAX_PATH_CHARS = 1024
MAX_COMPONENT_CHARS = 255
_DRIVE = re.compile(r"^[A-Za-z]:")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


class UnsafePath(ValueError):
    """`name` is not a safe relative path; `problem` says why."""

    def __init__(self, name: str, problem: str):
        self.name = name
        self.problem = problem
        super().__init__(f"{name!r}: {problem}")


def printable(name: str) -> str:
    """`name` with what UTF-8 cannot carry (bytes an archive decoded as lone surrogates) escaped as
    `\\udcNN`, so an error can name it in JSON."""
    return name.encode("utf-8", "backslashreplace").decode("utf-8")


def safe_relative_path(name: str) -> str:
    """`name` normalised (`./a//b` -> `a/b`), or UnsafePath."""
    if not name:
        raise UnsafePath(name, "empty file name")
    if printable(name) != name:
        raise UnsafePath(name, "the file name is not valid UTF-8")
    if len(name) > MAX_PATH_CHARS:
        raise UnsafePath(name, f"file name longer than {MAX_PATH_CHARS} characters")
    if "\\" in name:
        raise UnsafePath(name, "backslashes are not allowed in file names; use '/'")
    if _CONTROL.search(name):
        raise UnsafePath(name, "control characters are not allowed in file names")
    if name.startswith("/") or _DRIVE.match(name):
        raise UnsafePath(name, "absolute paths are not allowed; use a path relative to the upload")
    parts = [part for part in name.split("/") if part not in ("", ".")]
    if ".." in parts:
        raise UnsafePath(name, "'..' is not allowed in file names (it could escape the upload)")
    if not parts:
        raise UnsafePath(name, "the name has no file component")
    if any(len(part) > MAX_COMPONENT_CHARS for part in parts):
        raise UnsafePath(name, f"a path component is longer than {MAX_COMPONENT_CHARS} characters")
    return "/".join(parts)
