"""How another installed package adds commands to `nbake`: it declares an entry point in the group
`neuralbake.cli` naming a `Plugin`, which lists its commands by import path with a one-line summary. Only
the summary is read when `nbake --help` lists them; a command's module is imported when it runs (or its
own `--help` is asked for), so the server's heavy imports (torch, Ray) never slow the remote commands.

    [project.entry-points."neuralbake.cli"]
    server = "services.cli.plugin:PLUGIN"
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from typing import Any

import typer
from typer.core import TyperCommand

ENTRY_POINT_GROUP = "neuralbake.cli"


@dataclass(frozen=True)
class CommandRef:
    """A typer command function at `target` ("module:function"), run as `nbake <name>`."""

    name: str
    target: str
    summary: str  # what `nbake --help` shows without importing the target

    def load(self) -> TyperCommand:
        module, _, function = self.target.partition(":")
        app = typer.Typer(add_completion=False)
        app.command(self.name)(getattr(importlib.import_module(module), function))
        return typer.main.get_command(app)


@dataclass(frozen=True)
class Plugin:
    commands: tuple[CommandRef, ...] = ()
    scene_render: CommandRef | None = None  # `nbake render SCENE`: path tracing on this machine


@cache
def installed() -> tuple[Plugin, ...]:
    return tuple(point.load() for point in entry_points(group=ENTRY_POINT_GROUP))


def plugin_commands() -> dict[str, CommandRef]:
    return {ref.name: ref for plugin in installed() for ref in plugin.commands}


def scene_render() -> CommandRef | None:
    return next((p.scene_render for p in installed() if p.scene_render is not None), None)


class LazyCommand(TyperCommand):
    """A plugin's command as `nbake --help` lists it; running it imports and runs the real one."""

    def __init__(self, ref: CommandRef):
        super().__init__(ref.name, help=ref.summary)
        self.ref = ref

    def make_context(
        self, info_name: str | None, args: list[str], parent: typer.Context | None = None, **extra: Any
    ) -> typer.Context:
        return self.ref.load().make_context(info_name, args, parent, **extra)
