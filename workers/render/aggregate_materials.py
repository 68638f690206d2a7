"""Materials the path tracer draws as a volume over surfaces (a kind's neural shell, say) rather than as a
BSDF: plugins registered by name, like the BSDF families (`workers.render.bsdf`), that turn the surfaces
using a scene material of their `type` (a `workers.scene.format.spec.AggregateMaterial`) into the `Aggregate`
the integrator scatters in (`workers.render.aggregate`). The surfaces themselves keep the material's
`base` BSDF.

A family is registered as a "package.module:function" string, imported when a scene first uses it, so
registering one loads neither torch nor the family's code; the model kinds register theirs
(`workers.models.registry`). The function is called as function(scene, materials, view) -> Aggregate,
with the compiled scene, its materials of that type by name and the camera paths start from (at the size
rendered: a material may filter by the pixel's footprint). It finds the model's files with
`artifact_source` and raises `SceneError` naming the material's field (`materials.fur.path`) for what it
cannot use.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import AggregateMaterial, Camera
from workers.scene.portability.stored import artifact_folder

if TYPE_CHECKING:
    from workers.render.aggregate import Aggregate
    from workers.scene.geometry.compile import CompiledScene

_families: dict[str, str] = {}


def register_aggregate_material(name: str, builder: str) -> None:
    """Scene materials whose `type` is `name` are drawn by the Aggregate `builder` ("module:function")
    returns; registering a name again replaces it."""
    _families[name] = builder


def used_aggregate_materials(scene: CompiledScene) -> dict[str, dict[str, AggregateMaterial]]:
    """The scene's aggregate materials that some surface uses, by type, then by name (no pass over the
    triangles for a scene without any)."""
    by_type: dict[str, dict[str, AggregateMaterial]] = {}
    if not any(isinstance(m, AggregateMaterial) for m in scene.spec.materials.values()):
        return by_type
    used = {scene.material_names[i] for i in np.unique(scene.material_ids)}
    for name, material in scene.spec.materials.items():
        if name in used and isinstance(material, AggregateMaterial):
            by_type.setdefault(material.type, {})[name] = material
    return by_type


def scene_aggregate(scene: CompiledScene, view: Camera) -> Aggregate | None:
    """The Aggregate of the scene's aggregate materials that some surface uses; None when there are none.
    One family per scene: two families' events would need telling apart."""
    by_type = used_aggregate_materials(scene)
    if not by_type:
        return None
    if len(by_type) > 1:
        (first_type, first), (_, second) = ((k, next(iter(m))) for k, m in list(by_type.items())[:2])
        raise SceneError(
            f"materials.{second}", f"a scene takes aggregate materials of one type; {first!r} is {first_type}"
        )
    ((kind, materials),) = by_type.items()
    if kind not in _families:
        raise SceneError(
            f"materials.{next(iter(materials))}.type",
            f"no renderer is registered for {kind!r} materials (registered: {sorted(_families) or 'none'}); "
            "the model kinds register theirs (workers.models.registry.register_materials)",
        )
    module, _, function = _families[kind].partition(":")
    return getattr(importlib.import_module(module), function)(scene, materials, view)


def artifact_source(scene: CompiledScene, name: str, material: AggregateMaterial) -> tuple[str, Path]:
    """(field, folder) of the artifact the material `name` draws: its `path`, relative to the scene file, or
    its stored `artifact`, which a job of the server has fetched into the scene's folder. Anywhere else
    (`nbake render` of a local scene file) a stored artifact is a SceneError naming the field: this machine
    has no store to fetch it from."""
    if material.path is not None:
        folder = Path(material.path) if scene.base_dir is None else scene.base_dir / material.path
        return f"materials.{name}.path", folder
    field = f"materials.{name}.artifact"
    if scene.base_dir is None or not (folder := scene.base_dir / artifact_folder(material.artifact)).is_dir():
        raise SceneError(
            field,
            f"{material.artifact!r} names an artifact in the job server's store, which a job of the server "
            f"fetches into its scene's folder ({artifact_folder(material.artifact)}); to render elsewhere, "
            f"download it (`nbake download {material.artifact} -o DIR`) and name DIR in `path`",
        )
    return field, folder
