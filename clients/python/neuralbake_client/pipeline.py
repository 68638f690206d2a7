"""A bake pipeline file: which assets to bake into which kinds of model, and the gates each must pass.

    # nbake.yaml
    concurrency: 4            # jobs in flight at once
    timeout: 30m              # the whole build (s, m or h)
    assets:
      - cornell_box           # a built-in scene name
      - assets/chair          # a folder, uploaded (paths are relative to this file)
      - props/*.glb           # a glob
      - scene: assets/lamp.gltf
        kinds: [render]       # only some of the kinds below
    kinds:
      - kind: render
        preset: quick
        config: {spp: 16}
        gates: ["flip <= 0.1"]
      - kind: lod
        preset: quick
        gates: ["worse_than_one_spp == false", "flip <= previous + 0.01"]

Every asset is crossed with every kind (or its `kinds`): one item each, named `ASSET/KIND` (or the kind
entry's `name`). A typo anywhere is an error naming the place, before anything is uploaded.
"""

from __future__ import annotations

import glob
import hashlib
import json
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from neuralbake_client.durations import seconds
from neuralbake_client.gates import Gate, GateError

NAME = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"


class PipelineError(ValueError):
    """A pipeline file that cannot be read or does not validate; the message names the place."""


class KindEntry(BaseModel):
    """One kind of model every asset (that does not restrict its kinds) is baked into."""

    model_config = ConfigDict(extra="forbid")

    kind: str = Field(min_length=1, max_length=64)
    name: Annotated[str, Field(pattern=NAME, max_length=64)] | None = None
    preset: str | None = None
    config: dict[str, Any] = Field(default_factory=dict)
    seed: int | None = Field(None, ge=0)
    priority: int | None = None
    gates: list[str] = Field(default_factory=list)

    @field_validator("gates")
    @classmethod
    def _gates_parse(cls, gates: list[str]) -> list[str]:
        for text in gates:
            try:
                Gate.parse(text)
            except GateError as error:
                raise ValueError(str(error)) from None
        return gates

    @property
    def label(self) -> str:
        return self.name or self.kind

    def request(self) -> dict[str, Any]:
        """What identifies the job besides its scene (the config digest of the lock file)."""
        fields = {"kind": self.kind, "preset": self.preset, "config": self.config, "seed": self.seed}
        return {k: v for k, v in fields.items() if v is not None}


class AssetEntry(BaseModel):
    model_config = ConfigDict(extra="forbid")

    scene: str = Field(min_length=1, description="A built-in scene name, or a file, folder or glob.")
    kinds: list[str] | None = Field(None, description="Only the kind entries of these names.")


class Pipeline(BaseModel):
    model_config = ConfigDict(extra="forbid")

    assets: list[AssetEntry | str] = Field(min_length=1)
    kinds: list[KindEntry] = Field(min_length=1)
    concurrency: int = Field(4, ge=1, le=256)
    timeout: float = Field(3600.0, gt=0, description="Seconds for the whole build (or `30m`, `2h`).")

    @field_validator("timeout", mode="before")
    @classmethod
    def _duration(cls, value: Any) -> float:
        return seconds(value)

    @model_validator(mode="after")
    def _names_unique(self) -> Pipeline:
        labels = [entry.label for entry in self.kinds]
        repeated = sorted({label for label in labels if labels.count(label) > 1})
        if repeated:
            raise ValueError(f"kind entries {repeated} repeat: give each a distinct `name`")
        for asset in self.assets:
            unknown = set(asset.kinds or []) - set(labels) if isinstance(asset, AssetEntry) else set()
            if unknown:
                raise ValueError(f"asset {asset.scene!r}: kinds {sorted(unknown)} are not in `kinds`")
        return self


class Source(BaseModel):
    """One asset as the build found it: `label` names it in reports and the lock file; `path` is the local
    file or folder to upload (None: a built-in scene or an asset id, sent as it is); `digest` is the
    sha256 of its content (of the name, for a built-in scene)."""

    label: str
    path: Path | None
    digest: str


class Item(BaseModel):
    """One asset baked into one kind: a job of the build."""

    source: Source
    entry: KindEntry

    @property
    def name(self) -> str:
        return f"{self.source.label}/{self.entry.label}"

    @property
    def config_digest(self) -> str:
        text = json.dumps(self.entry.request(), sort_keys=True, separators=(",", ":"))
        return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def content_digest(path: Path) -> str:
    """sha256 of a file, or of a folder's regular files (relative names and contents, in name order, symlinks
    left out as the upload leaves them out): what decides whether an asset changed since the last build."""
    digest = hashlib.sha256()
    files = (
        [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file() and not p.is_symlink())
    )
    for file in files:
        name = file.name if file == path else file.relative_to(path).as_posix()
        digest.update(name.encode() + b"\0")
        with file.open("rb") as stream:
            while chunk := stream.read(1 << 20):
                digest.update(chunk)
        digest.update(b"\0")
    return "sha256:" + digest.hexdigest()


def sources(scene: str, base: Path) -> list[Source]:
    """The assets a pipeline's `scene` names: local files and folders (globs expanded, relative to `base`),
    or else the name itself (a built-in scene or an uploaded asset id)."""
    pattern = str(base / scene)
    paths = sorted(Path(p) for p in glob.glob(pattern, recursive=True)) if glob.has_magic(scene) else []
    if glob.has_magic(scene) and not paths:
        raise PipelineError(f"assets: {scene!r} matches no file under {base}")
    if not paths and (base / scene).exists():
        paths = [base / scene]
    if not paths:
        text = "sha256:" + hashlib.sha256(scene.encode()).hexdigest()
        return [Source(label=scene, path=None, digest=text)]
    return [
        Source(
            label=p.relative_to(base).as_posix() if p.is_relative_to(base) else str(p),
            path=p,
            digest=content_digest(p),
        )
        for p in paths
    ]


def load_pipeline(path: Path) -> Pipeline:
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise PipelineError(f"{path}: {error}") from None
    try:
        return Pipeline.model_validate(raw)
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'pipeline'}: {e['msg']}" for e in error.errors()
        )
        raise PipelineError(f"{path}: {problems}") from None


def items(pipeline: Pipeline, base: Path) -> list[Item]:
    """Every (asset, kind) of the pipeline, in file order; an asset named twice is baked as first named."""
    found: dict[str, tuple[Source, list[str] | None]] = {}
    for asset in pipeline.assets:
        entry = asset if isinstance(asset, AssetEntry) else AssetEntry(scene=asset)
        for source in sources(entry.scene, base):
            found.setdefault(source.label, (source, entry.kinds))
    return [
        Item(source=source, entry=kind)
        for source, only in found.values()
        for kind in pipeline.kinds
        if only is None or kind.label in only
    ]
