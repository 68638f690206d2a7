"""The scene an artifact carries, so the inference service can render the model in it without the job's
uploaded folder.

An artifact keeps the scene as JSON (`scene.json`) and the files it reads under `scene/`, named as in the
job's folder, so the spec's relative paths resolve unchanged: meshes, glTF buffers and USD layers, image
textures, an EXR environment, the folder of an artifact a material draws. The store keeps each file once
by its digest, so artifacts of one scene share them. Serving puts them in the node's scene cache, keyed by
their digests (`workers.scene.portability.stored`), where they outlive the download folder.

Objects a model replaces become stand-ins: their shape is a coarse sphere around their local bounds, with
their name, material, transform and instances unchanged. Their triangles are never traced, but their
placements are kept, and so are the scene bounds that lights depend on. The stand-ins' materials lose their
image textures, because the model predicts their base colour; their files are not kept. A scene whose files
cannot be kept (a job without its folder, an absolute path, a missing file) keeps the reason in place of
the scene, and renders fall back to a neutral background only when asked to.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from workers.scene.format.spec import (
    AggregateMaterial,
    ConstantBackground,
    DirectionalLight,
    EnvironmentMap,
    GltfShape,
    ImageTexture,
    Material,
    MeshShape,
    SceneObject,
    SceneSpec,
    SphereShape,
    UsdShape,
)
from workers.scene.geometry.compile import CompiledScene, compile_scene
from workers.scene.importers.usd import read_stage
from workers.scene.portability.stored import StoredFile, artifact_folder
from workers.scene.portability.stored import StoredScene as StoredFiles

SCENE_FILE = "scene.json"
SCENE_FILES = "scene"  # the folder of the files the scene reads, in an artifact
JSON = "application/json"
NEUTRAL_RADIANCE = 0.5  # a grey sky lighting the model from every direction
# and a sun from above, front left, so that the shape reads under the sky's flat light
NEUTRAL_SUN = DirectionalLight(direction=(0.4, -1.0, -0.6), irradiance=(2.0, 2.0, 2.0))
UNTEXTURED_BASE = (0.5, 0.5, 0.5)
# An icosahedron's inradius over its circumradius: the stand-in's triangles enclose its bounding sphere.
ICOSAHEDRON_INRADIUS = math.sqrt((5 + 2 * math.sqrt(5)) / 15)  # 0.7947


@dataclass(frozen=True)
class StoredScene:
    """The artifact's scene, or `None` and `reason` saying why it could not be kept.

    `files` are the files the spec reads, named relative to `root`, and `base` is the folder (relative to
    `root`) that the spec's relative paths resolve from: the job's folder when saved, the node's scene
    cache when loaded."""

    spec: SceneSpec | None
    standins: tuple[str, ...] = ()  # objects whose shape is a stand-in for the model
    reason: str = ""
    files: tuple[str, ...] = ()
    root: Path | None = None
    base: str = "."

    @property
    def base_dir(self) -> Path | None:
        return None if self.root is None else self.root / self.base

    def compiled(self) -> CompiledScene:
        """The kept scene's triangles, its files read from `base_dir`."""
        if self.spec is None:
            raise ValueError(f"the artifact keeps no scene: {self.reason}")
        return compile_scene(self.spec, self.base_dir)


class UnkeptFile(Exception):
    """A file the scene reads that an artifact cannot keep; the message says which and why."""


def standin_shape(local_bounds: np.ndarray) -> SphereShape:
    """A 20-triangle sphere enclosing the box `local_bounds` (2, 3)."""
    lo, hi = np.asarray(local_bounds, np.float64)
    half_diagonal = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    center = tuple(float(c) for c in (lo + hi) / 2)
    return SphereShape(center=center, radius=half_diagonal / ICOSAHEDRON_INRADIUS, subdivisions=0)


def untextured(material: Material) -> Material:
    """`material` with image textures replaced by a constant: a model predicts the base colour."""
    updates = {
        name: UNTEXTURED_BASE
        for name in ("reflectance", "diffuse")
        if isinstance(getattr(material, name, None), ImageTexture)
    }
    if isinstance(getattr(material, "base_color_texture", None), ImageTexture):
        updates["base_color_texture"] = None  # pbr: the factor stays
    return material.model_copy(update=updates)


def reads_file(obj: SceneObject) -> bool:
    return isinstance(obj.shape, MeshShape | GltfShape | UsdShape)


def file_references(spec: SceneSpec) -> dict[str, str]:
    """The fields of `spec` that name a file or folder, which only the job's folder holds (a stored
    artifact a material names included: the job fetched it into its folder) -> the path they name."""
    fields = {
        f"objects[{i}].shape.path": obj.shape.path for i, obj in enumerate(spec.objects) if reads_file(obj)
    }
    for name, material in spec.materials.items():
        if isinstance(material, AggregateMaterial):
            if material.path is not None:
                fields[f"materials.{name}.path"] = material.path
            else:
                fields[f"materials.{name}.artifact"] = str(artifact_folder(material.artifact))
            material, name = material.base, f"{name}.base"
        fields |= {
            f"materials.{name}.{field}.path": value.path
            for field, value in material
            if isinstance(value, ImageTexture)
        }
    if isinstance(spec.environment, EnvironmentMap) and spec.environment.path is not None:
        fields["environment.path"] = spec.environment.path
    return fields


def dependencies(path: Path) -> list[Path]:
    """Files that the mesh file at `path` reads besides itself: a .gltf's external buffers and images, a
    USD stage's other layers (the readers confine them to the file's folder)."""
    suffix = path.suffix.lower()
    if suffix == ".gltf":
        document = json.loads(path.read_text())
        uris = [item.get("uri") for key in ("buffers", "images") for item in document.get(key, [])]
        return [path.parent / unquote(uri) for uri in uris if uri and not uri.startswith("data:")]
    if suffix in (".usd", ".usda", ".usdc"):
        layers = {Path(layer.realPath) for layer in read_stage(path).GetUsedLayers() if layer.realPath}
        return sorted(layers - {path.resolve()})
    return []


def kept_files(references: Mapping[str, str], folder: Path) -> tuple[Path, tuple[str, ...], str]:
    """(root, names relative to it, the folder relative to it) of every file the `references` (field ->
    path relative to `folder`) read, or UnkeptFile."""
    folder = folder.resolve()
    paths: set[Path] = set()
    for field, reference in references.items():
        if Path(reference).is_absolute():
            raise UnkeptFile(f"{field} names an absolute path ({reference})")
        target = (folder / reference).resolve()
        if target.is_dir():
            paths |= {p for p in target.rglob("*") if p.is_file()}
        elif target.is_file():
            paths |= {target, *(p.resolve() for p in dependencies(target))}
        else:
            raise UnkeptFile(f"{field} names {reference}, which is not in the job's folder")
    root = Path(os.path.commonpath([folder, *paths]))
    names = tuple(sorted(p.relative_to(root).as_posix() for p in paths))
    return root, names, folder.relative_to(root).as_posix()


def portable_scene(
    spec: SceneSpec, standins: Mapping[str, np.ndarray], folder: Path | None = None
) -> StoredScene:
    """`spec` with the objects named in `standins` (name -> local bounds) replaced by stand-ins, only the
    materials some object uses, and the files the rest reads from `folder` (the job's); None, with the
    reason, when they cannot be kept."""
    objects = [
        obj.model_copy(update={"shape": standin_shape(standins[obj.name])}) if obj.name in standins else obj
        for obj in spec.objects
    ]
    kept_materials = {obj.material for obj in objects if obj.name not in standins}
    materials = {
        name: material if name in kept_materials else untextured(material)
        for name, material in spec.materials.items()
        if name in {obj.material for obj in objects}
    }
    portable = SceneSpec.model_validate(
        spec.model_copy(update={"objects": objects, "materials": materials}).model_dump()
    )
    references = file_references(portable)
    if not references:
        return StoredScene(portable, tuple(sorted(standins)))
    fields = ", ".join(references)
    if folder is None:
        reason = f"the scene reads files ({fields}) and the job has no folder they come from"
        return StoredScene(None, reason=reason)
    try:
        root, names, base = kept_files(references, Path(folder))
    except UnkeptFile as error:
        return StoredScene(None, reason=f"the artifact cannot keep the files the scene reads: {error}")
    return StoredScene(portable, tuple(sorted(standins)), files=names, root=root, base=base)


def neutral_scene(objects: list[SceneObject], materials: Mapping[str, Material]) -> SceneSpec:
    """`objects` alone under a uniform grey sky and a sun."""
    return SceneSpec(
        name="neutral",
        materials=dict(materials),
        objects=objects,
        lights=[NEUTRAL_SUN],
        environment=ConstantBackground(radiance=(NEUTRAL_RADIANCE,) * 3),
    )


def save_scene(folder: Path, stored: StoredScene) -> dict[str, tuple[str, str]]:
    """Write `scene.json` (the spec, or the reason there is none) and link or copy the files it reads under
    `scene/`; artifact name -> (path, media type: empty for the store to infer it from the name)."""
    folder = Path(folder)
    outputs = {}
    digests = {}
    for name in stored.files:
        target = folder / SCENE_FILES / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.unlink(missing_ok=True)  # a job run again writes its artifact again
        try:
            os.link(stored.root / name, target)
        except OSError:  # another file system
            shutil.copyfile(stored.root / name, target)
        with open(target, "rb") as file:
            digests[name] = f"sha256:{hashlib.file_digest(file, 'sha256').hexdigest()}"
        outputs[f"{SCENE_FILES}/{name}"] = (str(target), "")
    document = {
        "spec": None if stored.spec is None else stored.spec.model_dump(mode="json"),
        "standins": list(stored.standins),
        "reason": stored.reason,
        "files": digests,
        "base": stored.base,
    }
    path = folder / SCENE_FILE
    path.write_text(json.dumps(document, indent=2))
    return {SCENE_FILE: (str(path), JSON), **outputs}


def load_scene(folder: Path) -> StoredScene:
    """The artifact's scene in `folder`, its files verified into the node's scene cache (`folder` may be a
    download that is removed once the model is loaded)."""
    folder = Path(folder)
    path = folder / SCENE_FILE
    if not path.exists():
        return StoredScene(None, reason="the artifact was made before artifacts kept their scene")
    document = json.loads(path.read_text())
    spec = None if document["spec"] is None else SceneSpec.model_validate(document["spec"])
    stored = StoredScene(spec, tuple(document["standins"]), document["reason"])
    digests: dict[str, str] = document.get("files", {})
    if not digests:
        return stored
    key = hashlib.sha256(json.dumps(digests, sort_keys=True).encode()).hexdigest()
    files = {name: StoredFile(url=str(folder / SCENE_FILES / name), digest=d) for name, d in digests.items()}
    root = StoredFiles(key=key, files=files).local_folder()
    return replace(stored, files=tuple(digests), root=root, base=document["base"])
