"""A directory of numbered checkpoints on any fsspec file system, written atomically, the last K kept.

Each checkpoint is a folder `step-000000123/` of named files. It is written under a temporary name and
renamed into place, so a reader never sees half a checkpoint: a crash mid-write leaves only a temporary
folder, which listing ignores and the next save clears away.
"""

from __future__ import annotations

import re
import uuid

import fsspec

STEP_FOLDER = re.compile(r"^step-(\d{9})$")
TEMPORARY_PREFIX = ".partial-"


class CheckpointStore:
    """Numbered checkpoints under `root` (a local path or an fsspec URL such as `memory://` or `s3://`)."""

    def __init__(self, root: str, keep: int = 3) -> None:
        if keep < 1:
            raise ValueError(f"keep must be at least 1 so that a resume point exists, got {keep}")
        self.fs, self.root = fsspec.core.url_to_fs(str(root))
        self.keep = keep
        self.fs.makedirs(self.root, exist_ok=True)

    def sub(self, name: str) -> CheckpointStore:
        """The store of one part of a job (one of several models, say) in a folder of its own."""
        return CheckpointStore(self.fs.unstrip_protocol(f"{self.root}/{name}"), keep=self.keep)

    def _folder(self, step: int) -> str:
        return f"{self.root}/step-{step:09d}"

    def _entries(self) -> list[str]:
        return [path.rstrip("/").rsplit("/", 1)[-1] for path in self.fs.ls(self.root, detail=False)]

    def steps(self) -> list[int]:
        """Steps of the complete checkpoints, oldest first."""
        return sorted(int(m.group(1)) for name in self._entries() if (m := STEP_FOLDER.match(name)))

    def latest(self) -> int | None:
        steps = self.steps()
        return steps[-1] if steps else None

    def save(self, step: int, files: dict[str, bytes]) -> None:
        """Write the checkpoint of `step` (replacing one of the same step), then drop all but the last K."""
        for name in self._entries():
            if name.startswith(TEMPORARY_PREFIX):
                self.fs.rm(f"{self.root}/{name}", recursive=True)
        temporary = f"{self.root}/{TEMPORARY_PREFIX}{uuid.uuid4().hex}"
        self.fs.makedirs(temporary)
        for name, content in files.items():
            self.fs.pipe_file(f"{temporary}/{name}", content)
        final = self._folder(step)
        if self.fs.exists(final):
            self.fs.rm(final, recursive=True)
        self.fs.mv(temporary, final, recursive=True)
        for old in self.steps()[: -self.keep]:
            self.fs.rm(self._folder(old), recursive=True)

    def load(self, step: int) -> dict[str, bytes]:
        """All files of the checkpoint of `step`, by name."""
        folder = self._folder(step)
        if not self.fs.exists(folder):
            raise FileNotFoundError(f"no checkpoint for step {step} under {self.root}; have {self.steps()}")
        return {
            path.rstrip("/").rsplit("/", 1)[-1]: self.fs.cat_file(path)
            for path in self.fs.ls(folder, detail=False)
        }
