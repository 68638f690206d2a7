"""`nbake render`: path-trace a scene file or a built-in scene to an HDR EXR and a PNG preview."""

from __future__ import annotations

import math
from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError
from rich.console import Console

from services.cli.errors import fail, user_errors
from services.cli.outputs import RenderOutputs, as_display
from services.cli.progress import print_json, rays_per_second, render_progress
from workers.render.aggregate_materials import used_aggregate_materials
from workers.render.render import RenderResult, RenderSettings, render
from workers.scene.format.spec import Camera
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import load_scene

DEFAULT_OUTPUT_DIR = Path("out")


def render_command(
    scene: Annotated[
        str,
        typer.Argument(
            help="A scene file (.yaml, .yml, .json) or the name of a built-in scene (see `nbake scenes`).",
            show_default=False,
        ),
    ],
    spp: Annotated[int, typer.Option(min=1, help="Samples per pixel.")] = 64,
    width: Annotated[
        int | None,
        typer.Option(
            min=1, help="Image width in pixels. Default: the scene camera's, or kept to its aspect ratio."
        ),
    ] = None,
    height: Annotated[
        int | None,
        typer.Option(
            min=1, help="Image height in pixels. Default: the scene camera's, or kept to its aspect ratio."
        ),
    ] = None,
    max_depth: Annotated[int, typer.Option(min=1, help="Maximum number of bounces per path.")] = 8,
    seed: Annotated[int, typer.Option(min=0, help="Random seed; the same seed gives the same image.")] = 0,
    threads: Annotated[int, typer.Option(min=1, help="Worker threads.")] = 2,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="The EXR to write; other files go beside it. Default: out/<scene>.exr.",
            show_default=False,
        ),
    ] = None,
    aov: Annotated[
        bool,
        typer.Option(
            "--aov",
            help="Also write the G-buffers beside the image as <stem>.<name>.exr: position, normal, "
            "albedo, emission (RGB), roughness, depth, path_length (mean segments per path; one channel).",
        ),
    ] = False,
    png: Annotated[bool, typer.Option(help="Write an sRGB preview <stem>.png beside the EXR.")] = True,
    exposure: Annotated[
        float, typer.Option(help="Exposure of the PNG preview in stops; the EXR is never scaled.")
    ] = 0.0,
    json_lines: Annotated[
        bool, typer.Option("--json", help="Print progress and the result as JSON lines on stdout.")
    ] = False,
) -> None:
    """Path-trace SCENE to a linear HDR OpenEXR (float32) and an sRGB PNG preview.

    Example: nbake render cornell_box --spp 64 -o out/cornell_box.exr --aov
    """
    if not math.isfinite(exposure):
        fail("--exposure", "must be a finite number of stops")
    name = Path(scene).stem
    outputs = RenderOutputs.beside(output or DEFAULT_OUTPUT_DIR / f"{name}.exr", png=png, aovs=aov)
    stderr = Console(stderr=True)
    with user_errors():
        spec, base_dir = load_scene(scene)
        for note in spec.notes:  # what an importer defaulted or ignored
            stderr.print(f"note: {note}", markup=False, highlight=False)
        width, height = _resolution(spec.camera, width, height)
        settings = _settings(
            spp=spp, width=width, height=height, max_depth=max_depth, seed=seed, threads=threads, aovs=aov
        )
        outputs.check_writable()
        interactive = stderr.is_terminal and not json_lines
        with stderr.status(f"loading {name}") if interactive else nullcontext():
            compiled = compile_scene(spec, base_dir)
            if used_aggregate_materials(compiled):  # a kind's material (a `mesogan` shell): load the kinds
                from workers.models.registry import register_materials  # imports torch: only when needed

                register_materials()
        with render_progress(name, spp, json_lines, stderr) as progress:
            result = render(compiled, settings, progress=progress)
    outputs.write(result, exposure)
    _report(name, width, height, result, outputs, json_lines)


def _resolution(camera: Camera, width: int | None, height: int | None) -> tuple[int, int]:
    """Both given: as given. One given: the other follows the camera's aspect ratio. None: the camera's."""
    if width is None and height is None:
        return camera.width, camera.height
    if height is None:
        return width, max(1, round(width * camera.height / camera.width))
    if width is None:
        return max(1, round(height * camera.width / camera.height)), height
    return width, height


def _settings(**values) -> RenderSettings:
    """RenderSettings, with a value out of its range reported against the option that set it."""
    try:
        return RenderSettings(**values)
    except ValidationError as error:
        first = error.errors()[0]
        fail(f"--{str(first['loc'][0]).replace('_', '-')}", first["msg"])


def _report(
    name: str, width: int, height: int, result: RenderResult, outputs: RenderOutputs, json_lines: bool
) -> None:
    """Where the files are, how long it took and how fast it traced."""
    mrays = rays_per_second(result.rays_traced, result.seconds) / 1e6
    if json_lines:
        print_json(
            {
                "event": "done",
                "scene": name,
                "width": width,
                "height": height,
                "spp": result.spp,
                "seconds": round(result.seconds, 4),
                "rays_traced": result.rays_traced,
                "mrays_per_second": round(mrays, 3),
                "image": str(outputs.image),
                "preview": str(outputs.preview) if outputs.preview else None,
                "aovs": {aov: str(path) for aov, path in outputs.aovs.items()},
            }
        )
        return
    speed = f"{result.seconds:.2f} s ({mrays:.2f} Mrays/s)"
    print(f"rendered {name}: {width}x{height}, {result.spp} spp in {speed}")
    rows = [("image", outputs.image)]
    rows += [("preview", outputs.preview)] if outputs.preview else []
    rows += list(outputs.aovs.items())
    label_width = max(len(label) for label, _ in rows)
    for label, path in rows:
        print(f"  {label:<{label_width}}  {as_display(path)}")
