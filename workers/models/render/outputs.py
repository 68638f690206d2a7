"""The artifact files of a finished render, each written under a temporary name and renamed into place.

`image.exr` (float32 linear RGB), `preview.png` (sRGB), one `image.<aov>.exr` per G-buffer (separate files,
as `nbake render --aov` writes them, because every viewer opens them; `roughness`, `depth` and
`path_length` are single-channel `Y`) and `report.json`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from workers.render.render import RenderResult
from workers.scene.importers.image_io import write_exr, write_png

EXR = "image/x-exr"
PNG = "image/png"
JSON = "application/json"


def _atomic(path: Path, write: Callable[[Path], None]) -> str:
    temporary = path.with_name(f".partial-{path.name}")
    write(temporary)
    os.replace(temporary, path)
    return str(path)


def write_outputs(folder: Path, result: RenderResult, report: dict) -> dict[str, tuple[str, str]]:
    """Write every file into `folder`; returns artifact name -> (path, media type)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = {
        "image.exr": (_atomic(folder / "image.exr", lambda p: write_exr(p, result.image)), EXR),
        "preview.png": (_atomic(folder / "preview.png", lambda p: write_png(p, result.image)), PNG),
    }
    for name, layer in result.aov_images().items():
        file = f"image.{name}.exr"
        files[file] = (_atomic(folder / file, lambda p, layer=layer: write_exr(p, layer)), EXR)
    text = json.dumps(report, indent=2)
    files["report.json"] = (_atomic(folder / "report.json", lambda p: p.write_text(text)), JSON)
    return files
