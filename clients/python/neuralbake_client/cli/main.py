"""`nbake`: one typer app. The remote commands are registered here; commands of other installed packages
(the server's `serve`, `serve-inference`, `scenes` and local `render`) join through `plugins`, looked up
only when a name is not one of ours, so `nbake show` never scans the installed packages.
"""

from __future__ import annotations

from typing import Any

import typer
from typer.core import TyperGroup

from neuralbake_client.cli.bake import bake_command, diff_command
from neuralbake_client.cli.catalog import kinds_command, scenes_command
from neuralbake_client.cli.jobs import register as register_job_commands
from neuralbake_client.cli.plugins import LazyCommand, plugin_commands
from neuralbake_client.cli.query import query_command
from neuralbake_client.cli.render import SceneOrArtifact, render_command
from neuralbake_client.cli.tokens import tokens_app


class Nbake(TyperGroup):
    def list_commands(self, ctx: typer.Context) -> list[str]:
        ours = super().list_commands(ctx)
        return [*ours, *(name for name in plugin_commands() if name not in ours)]

    def get_command(self, ctx: typer.Context, name: str) -> Any:
        command = super().get_command(ctx, name)
        if command is None and (ref := plugin_commands().get(name)) is not None:
            return LazyCommand(ref)
        return command


app = typer.Typer(
    name="nbake",
    cls=Nbake,
    help="neuralbake: turn 3D scenes into neural rendering representations, trained on samples from its "
    "own Embree path tracer. The server package adds serve, serve-inference and local rendering.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,  # locals hold whole images and meshes
)
register_job_commands(app)  # submit, jobs, show, watch, cancel, download
app.command("bake")(bake_command)
app.command("diff")(diff_command)
app.command("kinds")(kinds_command)
app.command("scenes")(scenes_command)
app.command("query")(query_command)
app.command("render", cls=SceneOrArtifact)(render_command)
app.add_typer(tokens_app)  # tokens create | list | revoke
