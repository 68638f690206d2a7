"""The one place that knows which function builds each shape type's mesh, counts its triangles from its
description, and loads each environment type's image; geometry looks them up here by `type`, as the
renderer looks BSDF families up by name (`register_material`), so there is no chain of `if` over types.

Most builders read files or run generators, which live above geometry (`workers.scene.importers`,
`workers.scene.generators`) and build on its meshes; so they are named as "module:function" and imported on
first lookup, as `workers.models.registry` imports kinds. Adding a shape type is a line in `SHAPE_MESHES`
(and in `SHAPE_TRIANGLES` when its size is known before it is built) and a function beside its reader.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from functools import cache
from typing import Any

# type -> fn(shape, field, base_dir) -> MeshData, which `shape_mesh` then checks
SHAPE_MESHES = {
    "rectangle": "workers.scene.geometry.shapes:rectangle_mesh",
    "box": "workers.scene.geometry.shapes:box_mesh",
    "sphere": "workers.scene.geometry.shapes:sphere_mesh",
    "mesh": "workers.scene.importers.meshio:mesh_shape_mesh",
    "gltf": "workers.scene.importers.gltf:gltf_shape_mesh",
    "usd": "workers.scene.importers.usd:usd_shape_mesh",
    "procedural": "workers.scene.generators.catalogue:procedural_mesh",
}
# type -> fn(shape, field) -> the triangles of one placement (an upper bound for random generators); a type
# not listed (a file) is counted once it is read
SHAPE_TRIANGLES = {
    "rectangle": "workers.scene.geometry.shapes:rectangle_triangles",
    "box": "workers.scene.geometry.shapes:box_triangles",
    "sphere": "workers.scene.geometry.shapes:sphere_triangles",
    "procedural": "workers.scene.generators.catalogue:procedural_triangles",
}
# type -> fn(environment, field, base_dir) -> (H, W, 3) lat-long radiance; a type not listed has no image
ENVIRONMENT_IMAGES = {
    "envmap": "workers.scene.generators.envmaps:load_environment",
}


def registered(table: Mapping[str, str], type_: str) -> Callable[..., Any] | None:
    """The function `table` names for `type_`, imported on first use; None when the type is not listed."""
    target = table.get(type_)
    return None if target is None else _function(target)


@cache
def _function(target: str) -> Callable[..., Any]:
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)
