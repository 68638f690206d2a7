"""A directory of numbered checkpoints on any fsspec file system (a local folder, `s3://`), the last K kept.

Each checkpoint is a folder `step-000000123/` of named files and a commit marker, written last (beside,
then renamed into place, so that it is never seen half-written), that lists them. Object stores have no
atomic rename of a folder, so the marker is what makes a checkpoint visible: a reader only ever sees
steps whose marker is there, a crash mid-write leaves a folder without one (which the next save clears
away), and a checkpoint is removed marker first.
"""

from __future__ import annotations

import json
import re

import fsspec

STEP_FOLDER = re.compile(r"^step-(\d{9})$")
COMMIT_MARKER = "COMMITTED.json"
PARTIAL = ".partial"  # a marker being written (a driver killed mid-write leaves it, never an empty marker)


class CheckpointStore:
    """Numbered checkpoints under `root` (a local path or an fsspec URL such as `memory://` or `s3://`)."""

    def __init__(self, root: str, keep: int = 3) -> None:
        if keep < 1:
            raise ValueError(f"keep must be at least 1 so that a resume point exists, got {keep}")
        self.fs, self.root = fsspec.core.url_to_fs(str(root))
        self.root = self.root.rstrip("/")
        self.keep = keep
        self.fs.makedirs(self.root, exist_ok=True)

    def sub(self, name: str) -> CheckpointStore:
        """The store of one part of a job (one of several models, say) in a folder of its own."""
        return CheckpointStore(self.fs.unstrip_protocol(f"{self.root}/{name}"), keep=self.keep)

    def _folder(self, step: int) -> str:
        return f"{self.root}/step-{step:09d}"

    def _step_folders(self) -> dict[int, bool]:
        """Every step folder under the root -> whether its checkpoint is complete (has its marker).

        Listings are read afresh: another process (a driver on another node) may have written since."""
        self.fs.invalidate_cache(self.root)
        try:
            entries = self.fs.find(self.root, maxdepth=2, withdirs=True)
        except FileNotFoundError:
            return {}
        folders: dict[int, bool] = {}
        for path in entries:
            parts = path[len(self.root) + 1 :].split("/")
            match = STEP_FOLDER.match(parts[0])
            if match is not None:
                step = int(match.group(1))
                folders[step] = folders.get(step, False) or parts[1:] == [COMMIT_MARKER]
        return folders

    def steps(self) -> list[int]:
        """Steps of the complete checkpoints, oldest first."""
        return sorted(step for step, complete in self._step_folders().items() if complete)

    def latest(self) -> int | None:
        steps = self.steps()
        return steps[-1] if steps else None

    def save(self, step: int, files: dict[str, bytes]) -> None:
        """Write the checkpoint of `step` (replacing one of the same step), then drop all but the last K."""
        if COMMIT_MARKER in files:
            raise ValueError(f"{COMMIT_MARKER} is the checkpoint's commit marker, not a file name to save")
        for old, complete in self._step_folders().items():
            if not complete or old == step:  # a crashed write, or the checkpoint this one replaces
                self._remove(old)
        folder = self._folder(step)
        self.fs.makedirs(folder, exist_ok=True)
        for name, content in files.items():
            self.fs.pipe_file(f"{folder}/{name}", content)
        # the marker appears whole or not at all: written beside, then renamed (a PUT on an object store)
        self.fs.pipe_file(f"{folder}/{COMMIT_MARKER}{PARTIAL}", json.dumps(sorted(files)).encode())
        self.fs.mv(f"{folder}/{COMMIT_MARKER}{PARTIAL}", f"{folder}/{COMMIT_MARKER}")
        for old in self.steps()[: -self.keep]:
            self._remove(old)

    def _remove(self, step: int) -> None:
        folder = self._folder(step)
        if self.fs.exists(f"{folder}/{COMMIT_MARKER}"):
            self.fs.rm_file(f"{folder}/{COMMIT_MARKER}")
        if self.fs.exists(folder):
            self.fs.rm(folder, recursive=True)

    def load(self, step: int) -> dict[str, bytes]:
        """All files of the checkpoint of `step`, by name."""
        folder = self._folder(step)
        try:
            names = json.loads(self.fs.cat_file(f"{folder}/{COMMIT_MARKER}"))
        except FileNotFoundError:
            raise FileNotFoundError(
                f"no checkpoint for step {step} under {self.root}; have {self.steps()}"
            ) from None
        return {name: self.fs.cat_file(f"{folder}/{name}") for name in names}

    def delete(self) -> None:
        """Remove every checkpoint of the job (its sub-stores too): garbage collection of a finished job."""
        self.fs.invalidate_cache(self.root)
        if self.fs.exists(self.root):
            self.fs.rm(self.root, recursive=True)
