"""Staging an upload on local disk under limits, one file at a time, before anything is stored.

Limits are enforced while bytes stream in (declared sizes are checked first when known, but
never trusted), so an oversized or lying upload is rejected without being written in full.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from pydantic import BaseModel, ConfigDict, Field

from services.artifacts.paths import UnsafePath, printable, safe_relative_path
from workers.scene.importers.meshio import SUPPORTED_EXTENSIONS as MESH_SUFFIXES

PAYLOAD_TOO_LARGE = 413
BAD_REQUEST = 400


class UploadLimits(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    max_total_bytes: int = Field(default=512 << 20, gt=0, description="uncompressed bytes of all files")
    max_files: int = Field(default=1000, gt=0)
    max_file_bytes: int = Field(default=256 << 20, gt=0)
    max_compression_ratio: float = Field(default=100.0, gt=1.0, description="uncompressed / compressed")


class UploadError(ValueError):
    """The upload itself is unusable: `field` names the file (or `files`), `status` hints 400 or 413."""

    def __init__(self, field: str, problem: str, status: int = BAD_REQUEST):
        self.field = field
        self.problem = problem
        self.status = status
        super().__init__(f"{field}: {problem}")


class Staging:
    """Files of one upload under `root`, by normalised relative name."""

    def __init__(self, root: Path, limits: UploadLimits):
        self.root = root
        self.limits = limits
        self.files: dict[str, Path] = {}
        self.total_bytes = 0
        self._taken: dict[str, str] = {}  # case-folded name of every file and folder -> "file" | "folder"

    def add(self, raw_name: str, chunks: Iterable[bytes], declared_size: int | None = None) -> None:
        """Stage one file; UploadError on a bad name, a clash, a limit or an empty mesh."""
        name = self._claim(raw_name)
        if declared_size is not None:
            self._check_size(name, declared_size, self.total_bytes + declared_size)
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        size = 0
        with open(path, "xb") as out:
            for chunk in chunks:
                size += len(chunk)
                self.total_bytes += len(chunk)
                self._check_size(name, size, self.total_bytes)
                out.write(chunk)
        if size == 0 and PurePosixPath(name).suffix.lower() in MESH_SUFFIXES:
            raise UploadError(name, "the mesh file is empty")
        self.files[name] = path

    def _claim(self, raw_name: str) -> str:
        try:
            name = safe_relative_path(raw_name)
        except UnsafePath as error:
            raise UploadError(printable(raw_name) or "files", error.problem) from None
        if len(self.files) >= self.limits.max_files:
            raise UploadError(
                name, f"too many files: at most {self.limits.max_files} per upload", PAYLOAD_TOO_LARGE
            )
        parts = name.split("/")
        folders = ["/".join(parts[:i]).casefold() for i in range(1, len(parts))]
        key = name.casefold()
        if key in self._taken:
            what = "file" if self._taken[key] == "file" else "folder"
            raise UploadError(name, f"duplicate name: the upload already has a {what} called that")
        for folder in folders:
            if self._taken.get(folder) == "file":
                raise UploadError(name, f"{folder!r} is both a file and a folder in the upload")
        self._taken[key] = "file"
        self._taken.update(dict.fromkeys(folders, "folder"))
        return name

    def _check_size(self, name: str, file_bytes: int, total_bytes: int) -> None:
        if file_bytes > self.limits.max_file_bytes:
            raise UploadError(
                name, f"file larger than the limit of {self.limits.max_file_bytes} bytes", PAYLOAD_TOO_LARGE
            )
        if total_bytes > self.limits.max_total_bytes:
            raise UploadError(
                name,
                f"the upload exceeds the limit of {self.limits.max_total_bytes} bytes in total",
                PAYLOAD_TOO_LARGE,
            )
