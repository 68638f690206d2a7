"""The fenced blocks of a Markdown file and what the docs test does with each, read from the marker
comment on the line before the fence:

    <!-- example: run -->           run it (`sh`: each command in turn; `python`: as a script)
    <!-- example: run slow -->      run it only with the slow tests (it trains models for minutes)
    <!-- example: skip REASON -->   never run, for the reason given (a Kubernetes install, a GPU, ...)

A fenced block without a marker, a skip without a reason, a marker that is not one of these or a block
to run in a language the runner does not run is an error, so that no new example is left untested by
accident.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

FENCE = re.compile(r"^(\s*)(```+|~~~+)\s*([\w+-]*)")  # indented too: a block in a list item
MARKER = re.compile(r"^<!--\s*example:\s*(?P<action>\S+)\s*(?P<rest>.*?)\s*-->\s*$")
RUNNABLE = {"sh", "python"}


class MarkerError(ValueError):
    """A block the runner cannot classify; the message names the file and line."""


@dataclass(frozen=True)
class Block:
    path: Path
    line: int  # of the opening fence, 1-based
    language: str
    code: str
    action: str  # "run" or "skip"
    slow: bool = False
    reason: str = ""

    def __str__(self) -> str:
        return f"{self.path.parent.name}/{self.path.name}:{self.line} ({self.language or 'text'})"


def marker(path: Path, line: int, text: str, language: str) -> dict:
    found = MARKER.match(text.strip())
    where = f"{path}:{line}"
    if found is None:
        raise MarkerError(
            f"{where}: a fenced block needs a marker on the line before it: <!-- example: run --> "
            "(or `run slow`), or <!-- example: skip REASON -->"
        )
    action, rest = found["action"], found["rest"]
    if action == "skip":
        if not rest:
            raise MarkerError(f"{where}: `example: skip` needs a reason")
        return {"action": "skip", "reason": rest}
    if action != "run" or rest not in ("", "slow"):
        raise MarkerError(f"{where}: unknown marker {text.strip()!r}: use run, run slow or skip REASON")
    if language not in RUNNABLE:
        raise MarkerError(f"{where}: a {language or 'plain'} block cannot run (runnable: sh, python)")
    return {"action": "run", "slow": rest == "slow"}


def blocks(path: Path) -> list[Block]:
    """Every fenced block of `path` with its marker, in order."""
    lines = path.read_text().splitlines()
    found, index = [], 0
    while index < len(lines):
        opening = FENCE.match(lines[index])
        if opening is None:
            index += 1
            continue
        indent, fence, language = opening.groups()
        end = next((i for i in range(index + 1, len(lines)) if lines[i].strip().startswith(fence)), None)
        if end is None:
            raise MarkerError(f"{path}:{index + 1}: the fenced block is never closed")
        before = lines[index - 1] if index else ""
        code = "\n".join(line.removeprefix(indent) for line in lines[index + 1 : end]) + "\n"
        found.append(Block(path, index + 1, language, code, **marker(path, index + 1, before, language)))
        index = end + 1
    return found
