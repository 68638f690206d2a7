"""Writes `docs/kinds/<kind>.md` for every registered kind: a table of its config's parameters (dotted
names for nested parts, as `--set` takes them), each with its type, its value in every preset and its
description, read from the config's JSON schema (what `GET /v1/kinds/{kind}` serves as `config_schema`)
and the presets' resolved configs, as Mitsuba documents each plugin's parameters. Nothing on the pages is
written by hand, so they say what the code says: `make docs` (`python -m scripts.kind_docs`) rewrites
them, and `tests/unit/test_kind_docs.py` fails while one differs from what this would write.
"""

from __future__ import annotations

import importlib
import inspect
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workers.models.registry import KIND_MODULES, PRESET_NAMES, Kind, get_kind, kind_names

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "docs" / "kinds"
COMMAND = "make docs"
MISSING = "—"  # a parameter of a union member the preset does not choose


@dataclass
class Parameter:
    """One row: a leaf of the config, by its dotted name."""

    name: str
    types: list[str]
    description: str
    only_with: list[str] = field(default_factory=list)  # union members it belongs to, when not all


# ------------------------------------------------------------------ the schema


def resolved(node: dict, definitions: dict) -> dict:
    """`node` with a `$ref` (or pydantic's one-element `allOf` around one) replaced by its definition."""
    if len(node.get("allOf", ())) == 1:
        node = {**node["allOf"][0], **{k: v for k, v in node.items() if k != "allOf"}}
    if "$ref" in node:
        target = definitions[node["$ref"].rsplit("/", 1)[-1]]
        node = {**target, **{k: v for k, v in node.items() if k != "$ref"}}
    return node


def members(node: dict, definitions: dict) -> list[dict] | None:
    """The config models a field may hold (one, or a union's), or None for a leaf value."""
    node = resolved(node, definitions)
    if "properties" in node:
        return [node]
    union = [resolved(option, definitions) for option in node.get("oneOf", node.get("anyOf", ()))]
    if union and all("properties" in option for option in union):
        return union
    return None


def type_name(node: dict, definitions: dict) -> str:
    """A short, Python-like name of a leaf's type, with its bounds."""
    node = resolved(node, definitions)
    if "const" in node:
        return json.dumps(node["const"])
    if "enum" in node:
        return " | ".join(json.dumps(value) for value in node["enum"])
    options = node.get("anyOf", node.get("oneOf"))
    if options:
        return " | ".join(type_name(option, definitions) for option in options)
    if "properties" in node:
        return node.get("title", "object")
    kind = node.get("type")
    if kind == "array":
        if "prefixItems" in node:
            return "[" + ", ".join(type_name(item, definitions) for item in node["prefixItems"]) + "]"
        return f"list[{type_name(node.get('items', {}), definitions)}]"
    if kind == "object":
        values = node.get("additionalProperties")
        return f"dict[str, {type_name(values, definitions)}]" if isinstance(values, dict) else "dict"
    name = {"integer": "int", "number": "float", "string": "str", "boolean": "bool", "null": "None"}
    return name.get(kind, "any") + bounds(node)


def bounds(node: dict) -> str:
    low = (f"[{node['minimum']}", None) if "minimum" in node else None
    low = (f"({node['exclusiveMinimum']}", None) if "exclusiveMinimum" in node else low
    high = f"{node['maximum']}]" if "maximum" in node else None
    high = f"{node['exclusiveMaximum']})" if "exclusiveMaximum" in node else high
    if low and high:
        return f" in {low[0]}, {high}"
    if low:
        return (" ≥ " if low[0][0] == "[" else " > ") + low[0][1:]
    if high:
        return (" ≤ " if high[-1] == "]" else " < ") + high[:-1]
    return ""


def parameters(schema: dict, configs: list[dict]) -> list[Parameter]:
    """Every leaf of the config, in the schema's order, with the parts `configs` (the presets' resolved
    values) choose: of a union chosen by its discriminator (an encoding by `type`), the members some config
    chooses, whose fields they do not all have say which member they belong to; of a map of parts
    (`train.optimizers`), the keys some config gives."""
    definitions = schema.get("$defs", {})
    found: dict[str, Parameter] = {}

    def walk(model: dict, prefix: str, conditions: tuple[str, ...], member: str = "", shared=(), skip=()):
        for name, node in model["properties"].items():
            if name in skip:
                continue
            path, node = f"{prefix}{name}", resolved(node, definitions)
            own = (*conditions, member) if member and name not in shared else conditions
            options, entries = members(node, definitions), mapped(node, path)
            if entries:
                for key, part in entries.items():
                    walk({"properties": {key: part}}, f"{path}.", own)
            elif options and len(options) == 1:
                walk(options[0], f"{path}.", own)
            elif options and "discriminator" in node:
                union(node, options, path, own)
            else:
                add(path, type_name(node, definitions), node.get("description", ""), own)

    def union(node: dict, options: list[dict], path: str, conditions: tuple[str, ...]) -> None:
        key = node["discriminator"]["propertyName"]
        tags = [option["properties"][key].get("const") for option in options]
        add(f"{path}.{key}", " | ".join(json.dumps(t) for t in tags), node.get("description", ""), conditions)
        chosen = {value_at(config, f"{path}.{key}") for config in configs}
        shared = set.intersection(*(set(option["properties"]) for option in options))
        for option, tag in zip(options, tags, strict=True):
            if tag in chosen:
                walk(option, f"{path}.", conditions, f"{path}.{key}: {tag}", shared, skip=(key,))

    def mapped(node: dict, path: str) -> dict[str, dict]:
        """A map of parts' entries in any config, each with the part's schema; else nothing."""
        values = node.get("additionalProperties")
        if not isinstance(values, dict) or members(values, definitions) is None:
            return {}
        maps = [value_at(config, path) for config in configs]
        return {key: values for key in sorted({k for m in maps if isinstance(m, dict) for k in m})}

    def add(path: str, type_: str, description: str, conditions: tuple[str, ...]) -> None:
        row = found.setdefault(path, Parameter(path, [], description))
        row.description = row.description or description
        row.types += [type_] if type_ not in row.types else []
        row.only_with += [c for c in conditions if c not in row.only_with]

    walk(resolved(schema, definitions), "", ())
    return list(found.values())


# ------------------------------------------------------------------ the page


def summary(name: str) -> str:
    """The first paragraph of the kind's package docstring, on one line."""
    module = next(m for m in KIND_MODULES if importlib.import_module(m).KIND.name == name)
    return (inspect.getdoc(importlib.import_module(module)) or "").split("\n\n")[0].replace("\n", " ")


def value_at(config: dict, path: str) -> Any:
    node: Any = config
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            return MISSING
        node = node[part]
    return node


def cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def shown(value: Any) -> str:
    return MISSING if value is MISSING else cell(f"`{json.dumps(value)}`")


def page(kind: Kind) -> str:
    schema = kind.config_model.model_json_schema()
    presets = {name: kind.resolve_config(name, {}).model_dump(mode="json") for name in PRESET_NAMES}
    rows = parameters(schema, list(presets.values()))
    conditional = " A row `only with` a part's `type` applies when the part is of that type."
    lines = [
        f"# `{kind.name}` parameters",
        "",
        f"<!-- generated by `{COMMAND}` from {kind.config_model.__name__}'s schema; do not edit -->",
        "",
        summary(kind.name),
        "",
        f"A `{kind.name}` job's config is its preset ({', '.join(f'`{p}`' for p in PRESET_NAMES)}) with "
        f"your overrides merged in: `nbake submit SCENE --kind {kind.name} --preset quick --set name=value` "
        "(a dotted name sets a nested part), or `overrides` in `POST /v1/jobs`. "
        f"`GET /v1/kinds/{kind.name}` serves the presets' resolved configs and the JSON schema this table is "
        "made from (`config_schema`). An unknown name or a value out of range is an error naming it."
        + (conditional if any(row.only_with for row in rows) else ""),
        "",
        f"| parameter | type | {' | '.join(PRESET_NAMES)} | description |",
        "| --- | --- | " + "--- | " * len(PRESET_NAMES) + "--- |",
    ]
    for row in rows:
        values = " | ".join(shown(value_at(presets[p], row.name)) for p in PRESET_NAMES)
        note = f"only with `{'`, `'.join(row.only_with)}`. " if row.only_with else ""
        lines.append(
            f"| `{row.name}` | {cell(' | '.join(row.types))} | {values} | {cell(note + row.description)} |"
        )
    return "\n".join(lines) + "\n"


def index() -> str:
    lines = [
        "# Model kinds' parameters",
        "",
        f"<!-- generated by `{COMMAND}` (scripts/kind_docs.py); do not edit -->",
        "",
        "Every parameter of every registered kind's config, with its value in each preset. How to write a "
        "kind: [`../writing-a-kind.md`](../writing-a-kind.md).",
        "",
        "| kind | what it makes |",
        "| --- | --- |",
    ]
    for name in kind_names():
        what = summary(name).removeprefix(f"The `{name}` kind: ")
        lines.append(f"| [`{name}`]({name}.md) | {cell(what)} |")
    return "\n".join(lines) + "\n"


def pages() -> dict[Path, str]:
    """Every page this writes, by path."""
    kinds = {FOLDER / f"{name}.md": page(get_kind(name)) for name in kind_names()}
    return {FOLDER / "README.md": index()} | kinds


def main() -> None:
    FOLDER.mkdir(parents=True, exist_ok=True)
    written = pages()
    for stale in set(FOLDER.glob("*.md")) - set(written):
        stale.unlink()
    for path, text in written.items():
        path.write_text(text)
        print(path.relative_to(ROOT))


if __name__ == "__main__":
    main()
