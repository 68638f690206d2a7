"""How many triangles a scene makes, counted from its description before anything is built, and the
limit every process that builds geometry holds scenes to (a 250-byte scene can ask for billions).

The limit is `NBAKE_MAX_SCENE_TRIANGLES` (default 8M): compiling costs about 0.55 KB per triangle
(a 4.1M-triangle `fractal_tree` took +2.2 GB), so 8M is about 4.5 GB in the process that compiles it,
before a BVH or a sampler's copy; the largest generator defaults (`displaced_sphere`, ~1M) fit 8 times.
"""

from __future__ import annotations

import os

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.registry import SHAPE_TRIANGLES, registered

MAX_SCENE_TRIANGLES_ENV = "NBAKE_MAX_SCENE_TRIANGLES"
DEFAULT_MAX_SCENE_TRIANGLES = 8_000_000
# Placements an imported file may make (a USD PointInstancer's instances): each is a transform stored in
# every job's scene, and 100k of them made a 15 MB scene whatever their triangles.
MAX_SCENE_INSTANCES = 10_000


def max_scene_triangles() -> int:
    """The configured limit (the environment is read at each call, so a test or a server may set it)."""
    return int(os.environ.get(MAX_SCENE_TRIANGLES_ENV, DEFAULT_MAX_SCENE_TRIANGLES))


def shape_triangles(shape: spec.Shape, field: str) -> int | None:
    """Triangles of one placement of `shape` (an upper bound for random generators), or None for a mesh
    file, whose count is known only once it is read. Bad generator parameters raise a SceneError."""
    count = registered(SHAPE_TRIANGLES, shape.type)
    return None if count is None else count(shape, field)


def check_triangles(total: int, field: str, limit: int) -> None:
    """SceneError naming `field` (the object that crosses the limit) when `total` exceeds `limit`."""
    if total > limit:
        raise SceneError(
            field,
            f"the scene would have {total:,} triangles, over the limit of {limit:,} "
            f"({MAX_SCENE_TRIANGLES_ENV})",
        )


def scene_triangles(scene: spec.SceneSpec, limit: int | None = None) -> int:
    """Triangles of every placement of every shape that is not a mesh file, refused past `limit` (the
    configured one by default) naming the object that crosses it: what a submission checks without
    building anything (mesh files were counted when their upload was checked)."""
    limit = max_scene_triangles() if limit is None else limit
    total = 0
    for i, obj in enumerate(scene.objects):
        per_placement = shape_triangles(obj.shape, f"objects[{i}].shape") or 0
        total += per_placement * len(obj.instances or [None])
        check_triangles(total, placement_field(obj, i), limit)
    return total


def placement_field(obj: spec.SceneObject, index: int) -> str:
    """The field to blame: an object's instances when it has several, else a generator's parameters or
    the shape."""
    if obj.instances and len(obj.instances) > 1:
        return f"objects[{index}].instances"
    params = ".params" if isinstance(obj.shape, spec.ProceduralShape) else ""
    return f"objects[{index}].shape{params}"
