"""Variable scenes: what `SceneSpec.variables` means, as a map from the scene vector v in [0, 1]^K to a
concrete scene (Diolatzis, thesis Sec. 5.3.1: every variable normalised to [0, 1], the vector is the whole
state; a scene's fixed part is learned, v carries only what varies).

Each variable owns consecutive entries of v, in the order of `variables`: a vector-valued one (an offset, a
colour, the camera's position and target) one per component whose range is not empty, a scalar one (angle,
roughness, intensity, switch) one. A component maps linearly from its `min` at 0 to its `max` at 1; a switch
between n objects takes the k-th for v in [k/n, (k+1)/n) and the last at v = 1.

Geometry changes only by placement: a moved object keeps its mesh and gets a new transform (rotations about
the pivot first, then offsets), so a compiled variable scene re-places its triangles without reloading
them (`workers.scene.geometry.variable_scene`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from pydantic import ValidationError

if TYPE_CHECKING:  # the spec imports this module to check and apply its variables
    from workers.scene.format.spec import Material, SceneSpec, Variable

VECTOR_RANGES = {
    "translate": ("min", "max"),
    "albedo": ("min", "max"),
    "specular": ("min", "max"),
    "light_color": ("min", "max"),
    "light_position": ("min", "max"),
}
AXES = "xyz"
CHANNELS = "rgb"


# --------------------------------------------------------------------------- dimensions


def _varying(lo: Sequence[float], hi: Sequence[float]) -> list[int]:
    return [i for i, (a, b) in enumerate(zip(lo, hi, strict=True)) if a != b]


def dimension_labels(variable: Variable) -> list[str]:
    """The names of the variable's entries of v, e.g. `box.x`, `red_wall.g`, `camera.target.z`."""
    name = variable.name
    if variable.type in VECTOR_RANGES:
        letters = CHANNELS if variable.type in ("albedo", "specular", "light_color") else AXES
        return [f"{name}.{letters[i]}" for i in _varying(variable.min, variable.max)]
    if variable.type == "camera":
        position = _varying(variable.position_min, variable.position_max)
        target = _varying(variable.target_min, variable.target_max)
        return [f"{name}.position.{AXES[i]}" for i in position] + [f"{name}.target.{AXES[i]}" for i in target]
    return [name]


def scene_dimensions(scene: SceneSpec) -> int:
    return sum(len(dimension_labels(v)) for v in scene.variables)


def dimension_names(scene: SceneSpec) -> list[str]:
    """One label per entry of v, in order."""
    return [label for v in scene.variables for label in dimension_labels(v)]


def variable_slices(scene: SceneSpec) -> dict[str, slice]:
    """Each variable's entries of v."""
    out, start = {}, 0
    for variable in scene.variables:
        n = len(dimension_labels(variable))
        out[variable.name] = slice(start, start + n)
        start += n
    return out


# --------------------------------------------------------------------------- targets


def resolve_light(scene: SceneSpec, light: str) -> tuple[str, int]:
    """("lights", i) for `lights[i]`, ("objects", i) for an emitting object's name; ValueError otherwise."""
    if light.startswith("lights[") and light.endswith("]"):
        index = light[len("lights[") : -1]
        if index.isdigit() and int(index) < len(scene.lights):
            return "lights", int(index)
        raise ValueError(f"unknown light {light!r}: the scene has {len(scene.lights)} light(s)")
    for i, obj in enumerate(scene.objects):
        if obj.name == light:
            if obj.emission is None:
                raise ValueError(f"object {light!r} emits no light")
            return "objects", i
    raise ValueError(f"unknown light {light!r}: name an emitting object or lights[i]")


def _object_index(scene: SceneSpec, name: str) -> int:
    for i, obj in enumerate(scene.objects):
        if obj.name == name:
            return i
    known = ", ".join(o.name for o in scene.objects)
    raise ValueError(f"unknown object {name!r} (known: {known})")


def moved_objects(scene: SceneSpec) -> list[int]:
    """Indices of the objects some variable moves, turns or switches: the scene's dynamic geometry."""
    moved: set[int] = set()
    for variable in scene.variables:
        if variable.type in ("translate", "rotate"):
            moved.add(_object_index(scene, variable.object))
        elif variable.type == "switch":
            moved.update(_object_index(scene, name) for name in variable.objects)
        elif variable.type == "light_position":
            kind, index = resolve_light(scene, variable.light)
            if kind == "objects":
                moved.add(index)
    return sorted(moved)


# --------------------------------------------------------------------------- validation


def check_variables(scene: SceneSpec) -> None:
    """ValueError naming `variables[i].<field>` for an unknown target, an empty range, a duplicate name,
    or a range that makes the scene invalid at either end (each variable at 0 and at 1, the others at
    the middle of theirs, and every variable at 0 and at 1 together)."""
    if not scene.variables:
        return
    names: set[str] = set()
    for i, variable in enumerate(scene.variables):
        where = f"variables[{i}]"
        if variable.name in names:
            raise ValueError(f"{where}.name: duplicate variable name {variable.name!r}")
        names.add(variable.name)
        _check_target(scene, variable, where)
        if not dimension_labels(variable) or _empty_scalar_range(variable):
            field = "range_angle" if variable.type in ("rotate", "environment_rotation") else "max"
            if variable.type == "camera":
                field = "position_max"
            raise ValueError(f"{where}.{field}: the range is empty; a variable must vary")
    k = scene_dimensions(scene)
    slices = variable_slices(scene)
    for i, variable in enumerate(scene.variables):
        for end in (0.0, 1.0):
            v = np.full(k, 0.5)
            v[slices[variable.name]] = end
            _check_applies(scene, v, f"variables[{i}]", f"{variable.name} = {end:g}")
    for end in (0.0, 1.0):
        _check_applies(scene, np.full(k, end), "variables", f"every variable = {end:g}")


def _empty_scalar_range(variable: Variable) -> bool:
    if variable.type in ("rotate", "environment_rotation"):
        return variable.range_angle == 0
    if variable.type in ("roughness", "light_intensity"):
        return variable.min == variable.max
    return False


def _check_target(scene: SceneSpec, variable: Variable, where: str) -> None:
    try:
        if variable.type in ("translate", "rotate"):
            _object_index(scene, variable.object)
        elif variable.type == "switch":
            for name in variable.objects:
                _object_index(scene, name)
            if len(set(variable.objects)) < len(variable.objects):
                raise ValueError("an object appears twice")
        elif variable.type in ("albedo", "specular", "roughness"):
            _check_material(scene, variable)
        elif variable.type in ("light_intensity", "light_color", "light_position"):
            kind, index = resolve_light(scene, variable.light)
            if variable.type == "light_position" and kind == "lights" and scene.lights[index].type != "point":
                raise ValueError("a directional light has no position")
        elif variable.type == "environment_rotation":
            if scene.environment is None or scene.environment.type != "envmap":
                raise ValueError("the scene has no environment map to rotate")
        elif variable.type == "camera":
            lo = np.maximum(
                np.minimum(variable.position_min, variable.position_max),
                np.minimum(variable.target_min, variable.target_max),
            )
            hi = np.minimum(
                np.maximum(variable.position_min, variable.position_max),
                np.maximum(variable.target_min, variable.target_max),
            )
            if np.all(lo <= hi):
                raise ValueError("the target box meets the position box: the camera could look at itself")
    except ValueError as error:
        field = {
            "translate": "object",
            "rotate": "object",
            "switch": "objects",
            "albedo": "material",
            "specular": "material",
            "roughness": "material",
            "environment_rotation": "type",
            "camera": "target_min",
        }.get(variable.type, "light")
        raise ValueError(f"{where}.{field}: {error}") from None


def _check_material(scene: SceneSpec, variable: Variable) -> None:
    material = scene.materials.get(variable.material)
    if material is None:
        known = ", ".join(sorted(scene.materials))
        raise ValueError(f"unknown material {variable.material!r} (known: {known})")
    field = _material_field(material, variable.type)
    if field is None:
        raise ValueError(f"a {material.type} material has no {variable.type}")
    if variable.type == "albedo" and not isinstance(getattr(material, field), tuple):
        raise ValueError("the material's colour is a texture; a variable can only change a constant colour")


def _material_field(material: Material, what: str) -> str | None:
    """The field of `material` that a variable of type `what` sets, or None when it has none."""
    fields = {
        "albedo": {"diffuse": "reflectance", "plastic": "diffuse"},
        "specular": {"conductor": "specular"},
        "roughness": {"conductor": "roughness", "plastic": "roughness", "dielectric": "roughness"},
    }
    return fields[what].get(material.type)


def _check_applies(scene: SceneSpec, v: np.ndarray, where: str, setting: str) -> None:
    try:
        apply_variables(scene, v)
    except ValidationError as error:
        first = error.errors()[0]
        location = ".".join(str(p) for p in first["loc"])
        raise ValueError(f"{where}: at {setting} the scene is invalid ({location}: {first['msg']})") from None
    except ValueError as error:
        raise ValueError(f"{where}: at {setting} the scene is invalid ({error})") from None


# --------------------------------------------------------------------------- applying


def check_vector(scene: SceneSpec, v: Sequence[float] | np.ndarray) -> np.ndarray:
    """`v` as float64 of length K with entries in [0, 1]; ValueError naming `v` otherwise."""
    vector = np.asarray(v, dtype=np.float64).reshape(-1)
    k = scene_dimensions(scene)
    if len(vector) != k:
        raise ValueError(f"v: the scene has {k} dimension(s), got {len(vector)} value(s)")
    if not np.all(np.isfinite(vector)) or vector.min(initial=0.0) < 0 or vector.max(initial=1.0) > 1:
        raise ValueError("v: every entry must be a finite number in [0, 1]")
    return vector


def switch_index(u: float, n: int) -> int:
    """The alternative u in [0, 1] picks among n: floor(u n), clamped so that u = 1 picks the last."""
    return min(math.floor(u * n), n - 1)


def _lerp_vector(lo, hi, u: np.ndarray) -> tuple[float, ...]:
    out = np.asarray(lo, np.float64).copy()
    idx = _varying(lo, hi)
    out[idx] = out[idx] + u * (np.asarray(hi, np.float64)[idx] - out[idx])
    return tuple(float(x) for x in out)


def _axis_rotation(axis, degrees: float) -> np.ndarray:
    """Rodrigues' rotation about a unit `axis`."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    c, sn = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    cross = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return c * np.eye(3) + sn * cross + (1 - c) * np.outer(a, a)


def apply_variables(scene: SceneSpec, v: Sequence[float] | np.ndarray) -> SceneSpec:
    """The concrete scene at `v` (variables removed, hidden switch alternatives removed), validated."""
    vector = check_vector(scene, v)
    if not scene.variables:
        return scene
    data = scene.model_dump()
    data["variables"] = []
    slices = variable_slices(scene)
    rotations: dict[int, np.ndarray] = {}
    offsets: dict[int, np.ndarray] = {}
    hidden: set[int] = set()
    for variable in scene.variables:
        u = vector[slices[variable.name]]
        t = variable.type
        if t == "translate":
            i = _object_index(scene, variable.object)
            offsets[i] = offsets.get(i, np.zeros(3)) + _lerp_vector(variable.min, variable.max, u)
        elif t == "rotate":
            i = _object_index(scene, variable.object)
            r = _axis_rotation(variable.axis, variable.min_angle + float(u[0]) * variable.range_angle)
            pivot = np.asarray(variable.pivot, np.float64)
            m = np.eye(4)
            m[:3, :3], m[:3, 3] = r, pivot - r @ pivot
            rotations[i] = m @ rotations.get(i, np.eye(4))
        elif t == "switch":
            chosen = switch_index(float(u[0]), len(variable.objects))
            hidden.update(
                _object_index(scene, name) for k, name in enumerate(variable.objects) if k != chosen
            )
        elif t in ("albedo", "specular", "roughness"):
            material = data["materials"][variable.material]
            field = _material_field(scene.materials[variable.material], t)
            if t == "roughness":
                material[field] = variable.min + float(u[0]) * (variable.max - variable.min)
            else:
                material[field] = _lerp_vector(variable.min, variable.max, u)
        elif t in ("light_intensity", "light_color", "light_position"):
            _apply_light(scene, data, variable, u, offsets)
        elif t == "environment_rotation":
            rx, ry, rz = data["environment"]["rotate"]
            data["environment"]["rotate"] = (
                rx,
                ry + variable.min_angle + float(u[0]) * variable.range_angle,
                rz,
            )
        elif t == "camera":
            n_position = len(_varying(variable.position_min, variable.position_max))
            data["camera"]["position"] = _lerp_vector(
                variable.position_min, variable.position_max, u[:n_position]
            )
            data["camera"]["target"] = _lerp_vector(variable.target_min, variable.target_max, u[n_position:])
    for i in set(rotations) | set(offsets):
        m = rotations.get(i, np.eye(4)) @ scene.objects[i].transform.to_matrix()
        m[:3, 3] += offsets.get(i, np.zeros(3))
        data["objects"][i]["transform"] = {"matrix": tuple(tuple(float(x) for x in row) for row in m[:3])}
    data["objects"] = [obj for i, obj in enumerate(data["objects"]) if i not in hidden]
    return type(scene).model_validate(data)


def _apply_light(scene: SceneSpec, data: dict, variable: Variable, u: np.ndarray, offsets: dict) -> None:
    kind, index = resolve_light(scene, variable.light)
    target = data[kind][index]
    if kind == "objects":
        field = "emission"
    else:
        field = {"point": "intensity", "directional": "irradiance"}[target["type"]]
    if variable.type == "light_intensity":
        factor = variable.min + float(u[0]) * (variable.max - variable.min)
        target[field] = tuple(float(c) * factor for c in target[field])
    elif variable.type == "light_color":
        target[field] = _lerp_vector(variable.min, variable.max, u)
    elif kind == "objects":
        offsets[index] = offsets.get(index, np.zeros(3)) + _lerp_vector(variable.min, variable.max, u)
    else:
        offset = _lerp_vector(variable.min, variable.max, u)
        target["position"] = tuple(float(p) + o for p, o in zip(target["position"], offset, strict=True))


# --------------------------------------------------------------------------- serving


def vector_from_values(
    scene: SceneSpec, values: Mapping[str, float | Sequence[float] | str], normalised: bool = False
) -> np.ndarray:
    """The scene vector for values given by variable name: in the variable's own units (a switch by the
    chosen object's name or index; a vector by all three components, of which the varying ones count) or,
    with `normalised`, as its entries of v. Variables not named sit at the middle of their range.
    ValueError naming `values.<name>` for an unknown name, a wrong length or a value out of range."""
    slices = variable_slices(scene)
    v = np.full(scene_dimensions(scene), 0.5)
    by_name = {variable.name: variable for variable in scene.variables}
    for name, value in values.items():
        where = f"values.{name}"
        if name not in by_name:
            raise ValueError(f"{where}: unknown variable (known: {', '.join(by_name) or 'none'})")
        entries = slices[name]
        u = (
            _normalised(by_name[name], value, where)
            if not normalised
            else np.atleast_1d(np.asarray(value, float))
        )
        if len(u) != entries.stop - entries.start:
            raise ValueError(f"{where}: expected {entries.stop - entries.start} value(s), got {len(u)}")
        if not np.all(np.isfinite(u)) or u.min() < -1e-9 or u.max() > 1 + 1e-9:
            raise ValueError(f"{where}: outside the variable's range")
        v[entries] = np.clip(u, 0.0, 1.0)
    return v


def _normalised(variable: Variable, value, where: str) -> np.ndarray:
    t = variable.type
    if t == "switch":
        if isinstance(value, str):
            if value not in variable.objects:
                raise ValueError(f"{where}: {value!r} is not one of {variable.objects}")
            value = variable.objects.index(value)
        n = len(variable.objects)
        if not float(value).is_integer() or not 0 <= value < n:
            raise ValueError(f"{where}: a switch takes an object's name or an index below {n}")
        return np.array([(value + 0.5) / n])
    if isinstance(value, str):
        raise ValueError(f"{where}: expected a number or a list of numbers")
    x = np.atleast_1d(np.asarray(value, np.float64))
    if t in ("rotate", "environment_rotation"):
        return (x - variable.min_angle) / variable.range_angle
    if t in ("roughness", "light_intensity"):
        return (x - variable.min) / (variable.max - variable.min)
    if t == "camera":
        if len(x) != 6:
            raise ValueError(f"{where}: a camera takes position and target, six numbers")
        position = _inverse_lerp(variable.position_min, variable.position_max, x[:3])
        return np.concatenate([position, _inverse_lerp(variable.target_min, variable.target_max, x[3:])])
    if len(x) != 3:
        raise ValueError(f"{where}: expected three components")
    return _inverse_lerp(variable.min, variable.max, x)


def _inverse_lerp(lo, hi, x: np.ndarray) -> np.ndarray:
    idx = _varying(lo, hi)
    lo_, hi_ = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return (x[idx] - lo_[idx]) / (hi_[idx] - lo_[idx])
