"""Durations as a person writes them in a pipeline file or an option: `90`, `90s`, `30m`, `2h`, `2d`."""

from __future__ import annotations

import re

DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smhd])?\s*$", re.IGNORECASE)
SECONDS = {"s": 1, "m": 60, "h": 3600, "d": 86400, None: 1}


def seconds(text: str | float) -> float:
    """`90`, `90s`, `30m`, `2h`, `2d` as seconds."""
    if isinstance(text, int | float):
        return float(text)
    match = DURATION.match(text)
    if match is None:
        raise ValueError(f"{text!r}: a duration is a number with s, m, h or d (e.g. 30m)")
    return float(match[1]) * SECONDS[match[2] and match[2].lower()]
