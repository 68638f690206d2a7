"""The `nbake` command line: one typer app that every later command (serve, submit, ...) joins."""

from __future__ import annotations

import typer

from services.cli.jobs_commands import register as register_job_commands
from services.cli.render import render_command
from services.cli.serve_inference import serve_inference_command
from workers.scene.builtin import BUILTIN_SCENES

app = typer.Typer(
    name="nbake",
    help="neuralbake: turn 3D scenes into neural rendering representations, "
    "trained on samples from its own Embree path tracer.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,  # locals hold whole images and meshes
)

app.command("render")(render_command)
register_job_commands(app)  # submit, jobs, show, watch, cancel, download
app.command("serve-inference")(serve_inference_command)


@app.command("scenes")
def scenes_command() -> None:
    """List the built-in scenes that `nbake render NAME` accepts."""
    width = max(len(name) for name in BUILTIN_SCENES)
    for name in sorted(BUILTIN_SCENES):
        doc = (BUILTIN_SCENES[name].__doc__ or "").strip().splitlines()
        print(f"{name:<{width}}  {doc[0] if doc else ''}".rstrip())


import services.cli.serve  # noqa: E402, F401  (registers `nbake serve`)
