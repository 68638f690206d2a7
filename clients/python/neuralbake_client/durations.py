"""Durations as a person writes them in a pipeline file or an option: `90`, `90s`, `30m`, `2h`."""

from __future__ import annotations

import re

DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(s|m|h)?\s*$")
SECONDS = {"s": 1, "m": 60, "h": 3600, None: 1}


def seconds(text: str | float) -> float:
    """`90`, `90s`, `30m`, `2h` as seconds."""
    if isinstance(text, int | float):
        return float(text)
    match = DURATION.match(text)
    if match is None:
        raise ValueError(f"{text!r}: a duration is a number with s, m or h (e.g. 30m)")
    return float(match[1]) * SECONDS[match[2]]
