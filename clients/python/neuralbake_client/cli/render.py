"""`nbake render`: one command for two things. `nbake render ARTIFACT` (an artifact id `sha256:...` or a
job id `job-...`) asks the inference service for an image of a trained artifact; `nbake render SCENE` (a
scene file or a built-in scene name) path-traces the scene on this machine, which the server package's
plugin provides (see `plugins.Plugin.scene_render`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
import yaml
from typer.core import TyperCommand

from neuralbake_client.cli import plugins
from neuralbake_client.cli.output import Output
from neuralbake_client.cli.overrides import SetOption, parse_sets
from neuralbake_client.cli.query import ArtifactArgument, InputOption
from neuralbake_client.cli.remote import (
    USAGE,
    InferenceUrlOption,
    JsonOption,
    TokenOption,
    UrlOption,
    connect,
    exit_with,
    remote_errors,
)
from neuralbake_client.references import ARTIFACT_PREFIX, JOB_PREFIX, names_a_job, names_an_artifact

IMAGE_FORMATS = {".exr": "exr", ".png": "png"}


def names_a_model(target: str) -> bool:
    """A job or an artifact (`references`), unless a file of that name is there: a scene."""
    return (names_a_job(target) or names_an_artifact(target)) and not Path(target).exists()


def first_positional(args: list[str], takes_value: set[str]) -> str | None:
    """The first argument that is neither an option nor the value of one (options unknown here are taken
    to be flags)."""
    skip = False
    for arg in args:
        if skip:
            skip = False
        elif arg == "--":
            return None
        elif arg.startswith("-") and len(arg) > 1:
            skip = "=" not in arg and arg in takes_value
        else:
            return arg
    return None


class SceneOrArtifact(TyperCommand):
    """Runs the remote render for an artifact (or no target, e.g. `--help`), the local one for a scene."""

    def make_context(
        self, info_name: str | None, args: list[str], parent: typer.Context | None = None, **extra: Any
    ) -> typer.Context:
        takes_value = {
            name
            for p in self.params
            if p.param_type_name == "option" and not p.is_flag and not p.count
            for name in p.opts
        }
        target = first_positional(args, takes_value)
        if target is None or names_a_model(target):
            return super().make_context(info_name, args, parent, **extra)
        local = plugins.scene_render()
        if local is None:
            exit_with(
                USAGE,
                f"error: {target}: rendering a scene needs the server package (pip install neuralbake); "
                f"an artifact is named by its id ({ARTIFACT_PREFIX}...), its hex digest or its job's id "
                f"({JOB_PREFIX}...)",
            )
        return local.load().make_context(info_name, args, parent, **extra)


def read_camera(text: str) -> dict[str, Any]:
    """A YAML/JSON mapping given inline or in a file."""
    path = Path(text)
    try:
        camera = yaml.safe_load(path.read_text() if path.is_file() else text)
    except (OSError, yaml.YAMLError) as error:
        exit_with(USAGE, f"error: --camera: {error}")
    if not isinstance(camera, dict):
        exit_with(USAGE, "error: --camera: give a mapping such as '{position: [0, 1, 4], target: [0, 1, 0]}'")
    return camera


def render_command(
    artifact: ArtifactArgument,
    output: Annotated[
        Path, typer.Option("--output", "-o", help="out.exr (linear float32) or out.png (sRGB).")
    ],
    camera: Annotated[
        str | None,
        typer.Option(
            help="The view, for kinds that render one: a YAML/JSON mapping of position, target, up, fov, "
            "width and height, or a file holding one.",
            show_default=False,
        ),
    ] = None,
    input_: InputOption = None,
    set_: SetOption = None,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    inference_url: InferenceUrlOption = None,
    token: TokenOption = None,
) -> None:
    """Render ARTIFACT on the inference service (or, with the server package, a SCENE locally).

    ARTIFACT is an artifact id (sha256:...) or a job id; the kind's parameters go in --set, its input
    arrays, for kinds that take them, in --input (prt: environment=map.npy, a lat-long (H, W, 3) map;
    mesogan: mesh=soup.npy, (triangles, 3, 8) position, normal, UV per corner).

    Any other first argument is a scene file or a built-in scene name, path-traced on this machine.

    Its options: nbake render SCENE --help
    """
    image_format = IMAGE_FORMATS.get(output.suffix.lower())
    if image_format is None:
        exit_with(USAGE, f"error: --output: {output} must end in .exr or .png")
    from neuralbake_client.cli.array_files import read_inputs

    out, params, arrays = Output(json_lines), parse_sets(set_ or []), read_inputs(input_ or [])
    view = read_camera(camera) if camera is not None else None
    with remote_errors(), connect(url, token, inference_url) as client:
        image = client.render(artifact, view, params, arrays=arrays, image_format=image_format)
    try:
        image.save(output)
    except OSError as error:
        exit_with(USAGE, f"error: --output: {output}: {error}")
    frame_ms = None if image.frame_time_s is None else round(image.frame_time_s * 1000, 3)
    if out.json:
        out.line(
            "rendered",
            artifact_id=image.artifact_id,
            media_type=image.media_type,
            bytes=len(image.data),
            frame_time_ms=frame_ms,
            output=str(output),
        )
        return
    frame = f", frame {frame_ms:g} ms" if frame_ms is not None else ""
    print(f"rendered {image.artifact_id}: {output} ({image.media_type}, {len(image.data):,} bytes{frame})")
