"""The scene an artifact carries, so the inference service can render the model in it without the job's
uploaded folder.

An artifact keeps the scene as JSON, never its files. Objects a model replaces become stand-ins: their
shape is a coarse sphere around their local bounds, with their name, material, transform and instances
unchanged. Their triangles are never traced, but their placements are kept, and so are the scene bounds
that lights depend on. The stand-ins' materials lose their image textures, because the model predicts
their base colour. Anything else that reads a file from the job's folder makes the scene unportable: a
mesh, an image texture or an EXR environment. The artifact then keeps the reason in place of the scene,
and renders fall back to a neutral background only when asked to.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workers.scene.spec import (
    AggregateMaterial,
    Camera,
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

SCENE_FILE = "scene.json"
JSON = "application/json"
NEUTRAL_RADIANCE = 0.5  # a grey sky lighting the model from every direction
# and a sun from above, front left, so that the shape reads under the sky's flat light
NEUTRAL_SUN = DirectionalLight(direction=(0.4, -1.0, -0.6), irradiance=(2.0, 2.0, 2.0))
UNTEXTURED_BASE = (0.5, 0.5, 0.5)
# An icosahedron's inradius over its circumradius: the stand-in's triangles enclose its bounding sphere.
ICOSAHEDRON_INRADIUS = math.sqrt((5 + 2 * math.sqrt(5)) / 15)  # 0.7947
FRAMING_DIRECTION = np.array([0.45, 0.35, 1.0])  # from the model's centre towards a default camera


@dataclass(frozen=True)
class StoredScene:
    """The artifact's scene, or `None` and `reason` saying why it could not be kept."""

    spec: SceneSpec | None
    standins: tuple[str, ...] = ()  # objects whose shape is a stand-in for the model
    reason: str = ""


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


def file_references(spec: SceneSpec) -> list[str]:
    """The fields of `spec` that name a file, which only the job's folder holds (a stored artifact a
    material names included: the job fetched it into its folder)."""
    fields = [f"objects[{i}].shape.path" for i, obj in enumerate(spec.objects) if reads_file(obj)]
    for name, material in spec.materials.items():
        if isinstance(material, AggregateMaterial):
            fields.append(f"materials.{name}.{'path' if material.path is not None else 'artifact'}")
            material, name = material.base, f"{name}.base"
        fields += [
            f"materials.{name}.{field}.path" for field, value in material if isinstance(value, ImageTexture)
        ]
    if isinstance(spec.environment, EnvironmentMap) and spec.environment.path is not None:
        fields.append("environment.path")
    return fields


def portable_scene(spec: SceneSpec, standins: Mapping[str, np.ndarray]) -> StoredScene:
    """`spec` with the objects named in `standins` (name -> local bounds) replaced by stand-ins, and
    only the materials some object uses; None, with the reason, when the rest reads files."""
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
    portable = spec.model_copy(update={"objects": objects, "materials": materials})
    references = file_references(portable)
    if references:
        reason = (
            f"the scene reads files from the job's folder ({', '.join(references)}), which the artifact "
            "does not keep"
        )
        return StoredScene(None, reason=reason)
    return StoredScene(SceneSpec.model_validate(portable.model_dump()), tuple(sorted(standins)))


def neutral_scene(objects: list[SceneObject], materials: Mapping[str, Material]) -> SceneSpec:
    """`objects` alone under a uniform grey sky and a sun."""
    return SceneSpec(
        name="neutral",
        materials=dict(materials),
        objects=objects,
        lights=[NEUTRAL_SUN],
        environment=ConstantBackground(radiance=(NEUTRAL_RADIANCE,) * 3),
    )


def framing_camera(bounds: np.ndarray, fov: float = 40.0) -> Camera:
    """A camera that sees the box `bounds` (2, 3) whole, from the front, above and to the right."""
    lo, hi = np.asarray(bounds, np.float64)
    center, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    distance = 1.1 * radius / math.sin(math.radians(fov) / 2)
    direction = FRAMING_DIRECTION / np.linalg.norm(FRAMING_DIRECTION)
    position = center + distance * direction
    return Camera(position=tuple(position.tolist()), target=tuple(center.tolist()), fov=fov)


def save_scene(folder: Path, stored: StoredScene) -> dict[str, tuple[str, str]]:
    """Write `scene.json` (the spec, or the reason there is none); artifact name -> (path, media type)."""
    document = {
        "spec": None if stored.spec is None else stored.spec.model_dump(mode="json"),
        "standins": list(stored.standins),
        "reason": stored.reason,
    }
    path = Path(folder) / SCENE_FILE
    path.write_text(json.dumps(document, indent=2))
    return {SCENE_FILE: (str(path), JSON)}


def load_scene(folder: Path) -> StoredScene:
    path = Path(folder) / SCENE_FILE
    if not path.exists():
        return StoredScene(None, reason="the artifact was made before artifacts kept their scene")
    document = json.loads(path.read_text())
    spec = None if document["spec"] is None else SceneSpec.model_validate(document["spec"])
    return StoredScene(spec, tuple(document["standins"]), document["reason"])
