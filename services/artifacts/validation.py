"""Checking an uploaded scene before it is stored: it parses, its files are in the upload, the headers of its
textures are within bounds, it compiles.

Errors are SceneErrors naming the field (`objects[2].shape.path`); paths of the temporary
folder the upload was checked in are replaced by names inside the upload.
"""

from __future__ import annotations

import posixpath
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import SceneSpec
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.textures import check_texture_size, image_textures
from workers.scene.portability.io import load_scene

if TYPE_CHECKING:
    from services.geometry import GeometryProcesses

_ABSOLUTE = re.compile(r"^(/|[A-Za-z]:)")
_OPAQUE_KEYS = {"params"}  # generator parameters: free-form, never file references


def validate_scene(
    root: Path, scene_file: str, names: set[str], geometry: GeometryProcesses | None = None
) -> SceneSpec:
    """The scene in `root / scene_file`, where `names` are the upload's files; SceneError if unusable.

    Everything that reads the upload's files (the scene file, imported glTF/USD, image headers, the built
    geometry) runs in `geometry`'s child processes when given (a server: untrusted files never cost its
    memory or its GIL), in this process otherwise (a command line); only the small validated spec returns."""
    with _names_inside_upload(root):
        if geometry is None:
            return checked_scene(root, scene_file, names)
        return geometry.run(scene_file, checked_scene, root, scene_file, names)


def checked_scene(root: Path, scene_file: str, names: set[str]) -> SceneSpec:
    """The scene parsed, its references and textures checked and its geometry built (module docstring)."""
    spec, base_dir = load_scene(root / scene_file)
    check_references(spec, scene_file, names)
    for field, texture in image_textures(spec):
        check_texture_size(texture, field, base_dir)
    compile_scene(spec, base_dir)  # the geometry (triangle limit, degenerate meshes), the environment map
    return spec


def check_references(spec: SceneSpec, scene_file: str, names: set[str]) -> None:
    """Every file the scene names resolves, relative to the scene file, to a file of the upload, or to a
    folder of it (a mesogan material's artifact)."""
    scene_dir = posixpath.dirname(scene_file)
    for field, reference in file_references(spec.model_dump(mode="json", exclude_none=True)):
        if "\\" in reference or _ABSOLUTE.match(reference):
            raise SceneError(field, f"{reference!r} must be a '/'-separated path relative to the scene file")
        resolved = posixpath.normpath(posixpath.join(scene_dir, reference))
        if resolved == ".." or resolved.startswith("../"):
            raise SceneError(field, f"{reference!r} points outside the upload")
        if resolved not in names and not any(name.startswith(f"{resolved}/") for name in names):
            raise SceneError(
                field,
                f"{reference!r} is not in the upload (looked for {resolved!r}); upload the scene's folder "
                "(`nbake submit FOLDER`) to send the files it names",
            )


def file_references(data: Any, field: str = "") -> Iterator[tuple[str, str]]:
    """(dotted field, path) for every `path` string in a scene dump."""
    if isinstance(data, dict):
        for key, value in data.items():
            child = f"{field}.{key}" if field else key
            if key == "path" and isinstance(value, str):
                yield child, value
            elif key not in _OPAQUE_KEYS:
                yield from file_references(value, child)
    elif isinstance(data, list):
        for index, value in enumerate(data):
            yield from file_references(value, f"{field}[{index}]")


@contextmanager
def _names_inside_upload(root: Path) -> Iterator[None]:
    try:
        yield
    except SceneError as error:
        field, problem = error.field, error.problem
        for prefix in {f"{root.resolve()}/", f"{root}/"}:
            field, problem = field.replace(prefix, ""), problem.replace(prefix, "")
        raise SceneError(field, problem) from None
