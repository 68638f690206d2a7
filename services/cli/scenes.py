"""`nbake scenes`: the built-in scenes."""

from __future__ import annotations

from workers.scene.generators.builtin import BUILTIN_SCENES


def scenes_command() -> None:
    """List the built-in scenes that `nbake render NAME` accepts."""
    width = max(len(name) for name in BUILTIN_SCENES)
    for name in sorted(BUILTIN_SCENES):
        doc = (BUILTIN_SCENES[name].__doc__ or "").strip().splitlines()
        print(f"{name:<{width}}  {doc[0] if doc else ''}".rstrip())
