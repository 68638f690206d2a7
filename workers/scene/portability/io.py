"""Load a SceneSpec from a built-in name, a YAML/JSON file, a glTF file or a dict; write one back.

A glTF (`.gltf`, `.glb`) or USD (`.usda`, `.usdc`, `.usd`, `.usdz`) file is a scene by itself
(`workers.scene.importers.gltf`, `workers.scene.importers.usd`). A YAML/JSON scene
may `import:` one (a path relative to the scene file) and override parts of it: its `camera`,
`environment` and `name` replace the file's, its `materials` replace the file's of the same name (or add
new ones), its `lights` replace the file's, and its `objects` are added to the file's.

Every failure is a SceneError naming the field (a dotted path such as
`objects[2].shape.radius`) or, for unparsable files, the file itself.
"""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import SceneSpec
from workers.scene.generators.builtin import BUILTIN_SCENES, get_builtin
from workers.scene.importers.gltf import GLTF_SUFFIXES, import_gltf
from workers.scene.importers.usd import USD_SUFFIXES, import_usd

SCENE_FILE_SUFFIXES = (".yaml", ".yml", ".json")
IMPORTED_SCENE_SUFFIXES = GLTF_SUFFIXES + USD_SUFFIXES
# A scene file's values once YAML aliases are expanded, and how deep they nest. The largest built-in
# scene has about 700 values and nests 7 deep; a 700-byte alias bomb expands to 10^8 values.
MAX_SCENE_VALUES = 200_000
MAX_SCENE_DEPTH = 64
# A scene file's bytes, checked before it is read: 200,000 short values fit in about 2 MB of YAML, and a
# file past this is refused before a parser allocates for it.
MAX_SCENE_FILE_BYTES = 4 << 20
_FIELD_PREFIX = re.compile(r"^(?P<field>[A-Za-z_][\w\[\]\.]*): (?P<problem>.+)$", re.DOTALL)


def load_scene(source: str | Path | dict | SceneSpec) -> tuple[SceneSpec, Path | None]:
    """The validated scene and the folder its relative paths resolve against (None if it has no file)."""
    if isinstance(source, SceneSpec):
        return source, None
    if isinstance(source, dict):
        return scene_from_dict(source), None
    if isinstance(source, str) and source in BUILTIN_SCENES:
        return get_builtin(source), None
    path = Path(source)
    if path.suffix.lower() in IMPORTED_SCENE_SUFFIXES:
        return import_scene_file(path), path.resolve().parent
    if path.suffix.lower() not in SCENE_FILE_SUFFIXES:
        if path.exists():
            raise SceneError(str(path), f"a scene file must end in {', '.join(SCENE_FILE_SUFFIXES)}")
        return get_builtin(str(source)), None  # raises, listing the built-in scenes
    if not path.is_file():
        raise SceneError(str(path), "scene file not found")
    data = _parse_file(path)
    if "import" in data:
        data = with_import(data, path.resolve().parent)
    return scene_from_dict(data), path.resolve().parent


def import_scene_file(path: Path, prefix: str = "") -> SceneSpec:
    """A glTF or USD file's scene (`workers.scene.importers.gltf`, `workers.scene.importers.usd`); values
    our scene format cannot hold (a base colour above 1, say) are a SceneError naming the file and the
    field."""
    try:
        if path.suffix.lower() in GLTF_SUFFIXES:
            return import_gltf(path, prefix)
        return import_usd(path, prefix)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise SceneError(Path(path).name, f"{where}: {first['msg']}") from None


def with_import(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """`data` (a scene with an `import:` key) merged over the scene of the file it imports (module
    docstring); the imported scene's paths are made relative to `folder`, the scene file's."""
    data = dict(data)
    reference = data.pop("import")
    if not isinstance(reference, str) or Path(reference).suffix.lower() not in IMPORTED_SCENE_SUFFIXES:
        raise SceneError("import", f"give a glTF or USD file relative to the scene file, not {reference!r}")
    if Path(reference).is_absolute() or ".." in Path(reference).parts:
        raise SceneError("import", f"{reference!r} must stay inside the scene file's folder")
    parent = Path(reference).parent.as_posix()
    try:
        imported = import_scene_file(folder / reference, prefix="" if parent == "." else parent)
    except SceneError as error:
        raise SceneError(f"import.{error.field}", error.problem) from None
    merged = imported.model_dump(mode="json", exclude_none=True)
    replaced = {key for key in ("name", "camera", "environment", "lights") if key in data}
    merged.update({key: data[key] for key in replaced})
    merged["materials"] = {**merged["materials"], **data.get("materials", {})}
    merged["objects"] = merged["objects"] + list(data.get("objects", []))
    overridden = {"camera"} & replaced | ({"environment"} if replaced & {"environment", "lights"} else set())
    merged["notes"] = [n for n in merged["notes"] if n.split(":")[0] not in overridden]
    unknown = set(data) - set(merged) - {"materials", "objects"}
    merged.update({key: data[key] for key in unknown})  # validation names them
    return merged


def scene_from_dict(data: dict[str, Any]) -> SceneSpec:
    """Validate `data`; the first problem becomes a SceneError on its dotted field path."""
    check_nesting(data, "scene")
    try:
        return SceneSpec.model_validate(data)
    except ValidationError as error:
        field, problem = _first_problem(error, data)
        prefixed = _FIELD_PREFIX.match(problem) if not field else None
        if prefixed and prefixed["field"].split(".")[0].split("[")[0] in SceneSpec.model_fields:
            field, problem = prefixed["field"], prefixed["problem"]  # a scene-level check named the field
        raise SceneError(field or "scene", problem) from None


def _first_problem(error: ValidationError, data: dict[str, Any]) -> tuple[str, str]:
    """The first error's field and message; within a union, the deepest alternative (the one that matched)."""
    located = [(dotted_path(e["loc"], data), _message(e, data)) for e in error.errors()]
    first_field = located[0][0]
    same_field = [
        (f, m) for f, m in located if f == first_field or f.startswith((f"{first_field}.", f"{first_field}["))
    ]
    field, problem = max(same_field, key=lambda item: len(item[0]))
    return field, problem.removeprefix("Value error, ")


def _message(error: dict[str, Any], data: dict[str, Any]) -> str:
    """Pydantic's message, in the scene's words where it speaks of its own machinery: a value of several
    kinds (a material, a shape, an environment) whose `type` is missing or unknown lists the kinds."""
    if error["type"] == "union_tag_invalid":
        return f"type {error['ctx']['tag']!r} is none of {error['ctx']['expected_tags']}"
    if error["type"] == "union_tag_not_found":
        return f"no `type`: give one of {_expected_tags(error['loc'], data)}"
    return error["msg"]


def _expected_tags(loc: tuple[str | int, ...], data: dict[str, Any]) -> str:
    """The `type`s the value at `loc` may have (pydantic lists them only for a wrong one: ask with one)."""
    probe = copy.deepcopy(data)
    node: Any = probe
    for part in loc:
        if (isinstance(node, dict) and part in node) or (isinstance(part, int) and isinstance(node, list)):
            node = node[part]  # (a union label in the location is not a key of the value, and is skipped)
    if not isinstance(node, dict):
        return "its kinds"
    node["type"] = ""
    try:
        SceneSpec.model_validate(probe)
    except ValidationError as error:
        for again in error.errors():
            if again["type"] == "union_tag_invalid" and again["loc"] == loc:
                return again["ctx"]["expected_tags"]
    return "its kinds"


def dotted_path(loc: tuple[str | int, ...], data: Any) -> str:
    """`('objects', 2, 'shape', 'sphere', 'radius')` -> `objects[2].shape.radius`.

    Pydantic inserts union labels (a discriminator tag like `sphere`, or a type name like
    `tuple[...]`) into locations; walking the input alongside the location drops them.
    """
    path, node = "", data
    for part in loc:
        if isinstance(part, int):
            path += f"[{part}]"
            node = node[part] if isinstance(node, list | tuple) and -len(node) <= part < len(node) else None
        elif isinstance(node, dict) and part in node:
            path += f".{part}" if path else part
            node = node[part]
        elif (
            (isinstance(node, dict) and node.get("type") == part) or "[" in part or not isinstance(node, dict)
        ):
            continue  # a union label, not a field
        else:
            path += f".{part}" if path else part  # a missing field
            node = None
    return path


def check_nesting(data: Any, field: str) -> None:
    """SceneError if `data` nests deeper than MAX_SCENE_DEPTH or holds more than MAX_SCENE_VALUES values;
    walked without recursion."""
    stack, values = [(data, 1)], 0
    while stack:
        node, depth = stack.pop()
        if depth > MAX_SCENE_DEPTH:
            raise SceneError(field, f"values nest more than {MAX_SCENE_DEPTH} levels deep")
        values += len(node) if isinstance(node, dict | list | tuple) else 0
        if values > MAX_SCENE_VALUES:
            raise SceneError(field, f"more than {MAX_SCENE_VALUES} values, over the limit (MAX_SCENE_VALUES)")
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list | tuple) else ()
        stack.extend((child, depth + 1) for child in children if isinstance(child, dict | list | tuple))


class _Unbounded(yaml.YAMLError):
    """A document whose values, once aliases are expanded, are too many or endless."""


_LibYamlLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # LibYAML: composes 30x faster


class _BoundedLoader(_LibYamlLoader):
    """A safe loader that refuses, once a document is composed and before any value is built, a node graph
    whose aliases expand past MAX_SCENE_VALUES values or that refers to itself (a "billion laughs" bomb
    costs a few hundred bytes of YAML and the whole memory of whoever walks it). `_check_events` bounds
    what is composed."""

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None:
            _expanded_size(node)
        return node


def _check_events(text: str) -> None:
    """Counts values and nesting in the parser's event stream, before a node is composed: a plain list of
    1.5M ones composes into a gigabyte of nodes, and LibYAML's composer recurses without a limit."""
    values = depth = 0
    try:
        for event in yaml.parse(text, Loader=_LibYamlLoader):
            if isinstance(event, yaml.ScalarEvent | yaml.AliasEvent | yaml.CollectionStartEvent):
                values += 1
                if values > MAX_SCENE_VALUES:
                    raise _Unbounded(f"the file holds more than {MAX_SCENE_VALUES} values, over the limit")
            if isinstance(event, yaml.CollectionStartEvent):
                depth += 1
                if depth > MAX_SCENE_DEPTH:
                    raise RecursionError
            elif isinstance(event, yaml.CollectionEndEvent):
                depth -= 1
    except yaml.MarkedYAMLError as error:
        if "nesting depth" in str(error.problem):  # LibYAML's own limit (1000), met while it looks ahead
            raise RecursionError from None
        raise


def _expanded_size(root: yaml.Node) -> int:
    """Values under `root` with every alias expanded, memoised per node (aliases share their node)."""
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        children = _children(node)
        if children_done:
            on_path.discard(key)
            sizes[key] = 1 + sum(sizes[id(child)] for child in children)
            if sizes[key] > MAX_SCENE_VALUES:
                raise _Unbounded(f"aliases expand to more than {MAX_SCENE_VALUES} values")
            continue
        if key in sizes:
            continue
        if key in on_path:
            raise _Unbounded("an alias refers to a value that contains it")
        on_path.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in children if id(child) not in sizes)
    return sizes[id(root)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    return list(node.value) if isinstance(node, yaml.SequenceNode) else []


def _parse_file(path: Path) -> dict[str, Any]:
    """YAML or JSON text -> a mapping; syntax errors name the file and line."""
    try:
        if (size := path.stat().st_size) > MAX_SCENE_FILE_BYTES:
            problem = f"the scene file is {size:,} bytes, over the limit of {MAX_SCENE_FILE_BYTES:,} bytes"
            raise SceneError(str(path), problem)
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SceneError(str(path), f"cannot read scene file: {error}") from error
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            _check_events(text)
            data = yaml.load(text, _BoundedLoader)
    except RecursionError:
        raise SceneError(str(path), f"values nest more than {MAX_SCENE_DEPTH} levels deep") from None
    except _Unbounded as error:
        raise SceneError(str(path), f"refused YAML: {error}") from None
    except json.JSONDecodeError as error:
        raise SceneError(
            str(path), f"malformed JSON at line {error.lineno}, column {error.colno}: {error.msg}"
        ) from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or str(error)
        raise SceneError(str(path), f"malformed YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise SceneError(str(path), f"a scene file must hold a mapping, not {type(data).__name__}")
    check_nesting(data, str(path))
    return data


def dump_scene(scene: SceneSpec, path: str | Path) -> Path:
    """Write `scene` as YAML or JSON (by suffix) so that `load_scene` reads back an equal spec."""
    path = Path(path)
    data = scene.model_dump(mode="json", exclude_none=True)
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    elif path.suffix.lower() in (".yaml", ".yml"):
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    else:
        raise SceneError(str(path), f"a scene file must end in {', '.join(SCENE_FILE_SUFFIXES)}")
    return path
