"""`nbake kinds [KIND]` and `nbake scenes`: what the server can make, asked of the server, so that a
client-only install (a CI image) sees the same list the server accepts."""

from __future__ import annotations

from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.remote import JsonOption, TokenOption, UrlOption, connect, remote_errors


def flat(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested config as dotted names (`train.steps`), the way `nbake submit --set` names them."""
    rows: dict[str, Any] = {}
    for name, value in config.items():
        if isinstance(value, dict) and value:
            rows |= flat(value, f"{prefix}{name}.")
        else:
            rows[f"{prefix}{name}"] = value
    return rows


def kinds_command(
    kind: Annotated[str | None, typer.Argument(help="Show this kind's parameters in every preset.")] = None,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """List the server's model kinds, or one kind's parameters with each preset's value."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        found = [client.kind(kind)] if kind else client.kinds()
    if out.json:
        for info in found:
            out.line("kind", **info.model_dump(mode="json", exclude=None if kind else {"config_schema"}))
        return
    if kind is None:
        for info in found:
            what = "trains a model" if info.trains else "path-traces"
            print(f"{info.name:<10}  {what:<14}  example: --kind {info.name} {info.example_scene}")
        return
    info = found[0]
    presets = {preset.name: flat(preset.config) for preset in info.presets}
    table = Table("parameter", *presets, title=f"{info.name}: `--set NAME=VALUE` overrides a preset's value")
    for name in next(iter(presets.values())):
        table.add_row(name, *(repr(values.get(name)) for values in presets.values()))
    Console().print(table)
    print(f"Each parameter's meaning: docs/kinds/{info.name}.md, or `nbake kinds {info.name} --json`.")


def scenes_command(json_lines: JsonOption = False, url: UrlOption = None, token: TokenOption = None) -> None:
    """List the server's built-in scenes (what a job's or `nbake render`'s SCENE may name)."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        scenes = client.scenes()
    width = max((len(scene.name) for scene in scenes), default=0)
    for scene in scenes:
        if out.json:
            out.line("scene", **scene.model_dump())
        else:
            print(f"{scene.name:<{width}}  {scene.description}".rstrip())
