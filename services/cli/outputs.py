"""The files one `nbake render` writes, checked before rendering and written after.

Everything sits beside the EXR and shares its stem: `<stem>.exr` (linear HDR, float32),
`<stem>.png` (sRGB preview) and, with `--aov`, one `<stem>.<aov>.exr` per G-buffer. Separate
files rather than EXR layers because every image viewer opens them; `roughness`, `depth` and
`path_length` are single-channel (`Y`), the others RGB. Writability is probed up front so that a long render
never ends in an unwritable path.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from services.cli.errors import fail
from workers.render.render import AOV_NAMES, RenderResult
from workers.scene.importers.image_io import write_exr, write_png


@dataclass(frozen=True)
class RenderOutputs:
    image: Path
    preview: Path | None
    aovs: dict[str, Path]

    @classmethod
    def beside(cls, image: Path, png: bool, aovs: bool) -> RenderOutputs:
        if image.suffix.lower() != ".exr":
            fail("--output", f"{image} must end in .exr (the preview and G-buffers are written beside it)")
        return cls(
            image=image,
            preview=image.with_suffix(".png") if png else None,
            aovs={name: image.with_suffix(f".{name}.exr") for name in AOV_NAMES} if aovs else {},
        )

    def files(self) -> list[Path]:
        return [self.image, *([self.preview] if self.preview else []), *self.aovs.values()]

    def check_writable(self) -> None:
        """Create the output folder and prove each file can be opened for writing, or fail."""
        folder = self.image.parent
        blocking = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()), None)
        if blocking is not None:
            fail("--output", f"cannot create the folder {folder}: {blocking} is a file")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            fail("--output", f"cannot create the folder {folder}: {error.strerror or error}")
        for path in self.files():
            if path.is_dir():
                fail("--output", f"{path} is a folder")
            existed = path.exists()
            try:
                with path.open("ab"):
                    pass
            except OSError as error:
                fail("--output", f"cannot write {path}: {error.strerror or error}")
            if not existed:
                path.unlink()

    def write(self, result: RenderResult, exposure: float) -> None:
        try:
            write_exr(self.image, result.image)
            if self.preview:
                write_png(self.preview, result.image, exposure=exposure)
            layers = result.aov_images()
            for name, path in self.aovs.items():
                write_exr(path, layers[name])
        except (OSError, RuntimeError) as error:  # OpenEXR reports I/O failures as RuntimeError
            fail("--output", f"cannot write the output: {error}")


def as_display(path: Path) -> str:
    """A path relative to the working directory when it lies inside it (shorter to read and copy)."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)
