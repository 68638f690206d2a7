"""The mesogan material of scene files (`workers.scene.format.spec.MesoganMaterial`): a trained artifact's
generated fur, grass or carpet on a shell over the surfaces that use the material, drawn by the path
tracer as the aggregate `covering.shell_aggregate` builds, as the kind's own `:render` draws it. The kind
registers it under its name (`KIND.materials`, `workers.render.aggregate_materials`).

The artifact is the folder `path` names, relative to the scene file, or the stored `artifact` a server job
fetched (`aggregate_materials.artifact_source`); structure, appearance and shell height left out are the
artifact's own (what its job rendered); the shell height may be relative to the covered surfaces' size
(`workers.scene.format.spec.ShellHeight`).
"""

from __future__ import annotations

import torch
from pydantic import ValidationError

from workers.models.mesogan import artifact
from workers.models.mesogan.aggregate import ShellAggregate
from workers.models.mesogan.covering import shell_aggregate
from workers.render.aggregate_materials import artifact_source
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Camera, MesoganMaterial
from workers.scene.geometry.compile import CompiledScene


def draw(scene: CompiledScene, materials: dict[str, MesoganMaterial], view: Camera) -> ShellAggregate:
    """The registered family: the shell of the scene's one mesogan material (module docstring)."""
    name, *others = materials
    if others:
        raise SceneError(f"materials.{others[0]}", f"a scene takes one mesogan material; {name!r} is one")
    material = materials[name]
    field, folder = artifact_source(scene, name, material)
    source = material.path or material.artifact
    if not (folder / artifact.MANIFEST).is_file():
        problem = (
            f"holds no {artifact.MANIFEST}: not a mesogan artifact" if folder.is_dir() else "no such folder"
        )
        raise SceneError(field, f"{source!r} ({folder}): {problem}")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        config, model = artifact.load(folder, device)
    except (OSError, ValueError, KeyError, ValidationError) as error:
        raise SceneError(field, f"{source!r} is not a usable mesogan artifact: {error}") from None
    return shell_aggregate(
        scene,
        [name],
        model,
        config,
        material.structure or config.structure,
        material.appearance or config.appearance,
        material.seed,
        material,
        view,
        (f"materials.{name}", f"materials.{name}."),
    )
