"""The lock file of a build: for every item, which asset content and which config gave which artifact, with
the artifact's metrics. The next build reuses an artifact whose asset digest and config digest are
unchanged without submitting anything, and measures its regression gates against these metrics; `nbake
diff` compares two of them.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, Field, ValidationError

LOCK_VERSION = 1


class LockEntry(BaseModel):
    asset: str = Field(description="The asset's label in the pipeline (a path or a scene name).")
    kind: str
    asset_digest: str = Field(description="sha256 of the asset's files (of its name, for a built-in scene).")
    config_digest: str = Field(description="sha256 of the kind entry's kind, preset, config and seed.")
    scene: str = Field(description="What the job was given: an uploaded asset id or a scene name.")
    job_id: str
    artifact_id: str
    metrics: dict[str, float] = Field(default_factory=dict)


class BuildLock(BaseModel):
    version: int = LOCK_VERSION
    entries: dict[str, LockEntry] = Field(default_factory=dict, description="By item name (ASSET/KIND).")

    @classmethod
    def read(cls, path: Path) -> BuildLock:
        """The lock at `path`; an empty one when there is none. A damaged lock is an error, not ignored:
        a build that silently forgot its previous artifacts would pass every regression gate."""
        if not path.exists():
            return cls()
        try:
            lock = cls.model_validate_json(path.read_bytes())
        except (OSError, ValidationError) as error:
            raise ValueError(f"{path}: not a build lock ({error})") from None
        if lock.version != LOCK_VERSION:
            raise ValueError(f"{path}: lock version {lock.version}; this client reads {LOCK_VERSION}")
        return lock

    def write(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(path.name + ".partial")
        partial.write_text(self.model_dump_json(indent=2) + "\n")
        partial.replace(path)  # a build killed while writing leaves the previous lock whole


class EntryChange(BaseModel):
    """One item between two locks: `added`, `removed`, `changed` (another artifact) or `same`."""

    name: str
    change: str
    before: LockEntry | None = None
    after: LockEntry | None = None

    def metric_rows(self) -> list[tuple[str, float | None, float | None]]:
        """(metric, before, after) for every metric either side has, in name order."""
        left = self.before.metrics if self.before else {}
        right = self.after.metrics if self.after else {}
        return [(m, left.get(m), right.get(m)) for m in sorted(set(left) | set(right))]


def diff_locks(before: BuildLock, after: BuildLock) -> list[EntryChange]:
    changes = []
    for name in sorted(set(before.entries) | set(after.entries)):
        old, new = before.entries.get(name), after.entries.get(name)
        if old is None:
            change = "added"
        elif new is None:
            change = "removed"
        else:
            change = "same" if old.artifact_id == new.artifact_id else "changed"
        changes.append(EntryChange(name=name, change=change, before=old, after=new))
    return changes
