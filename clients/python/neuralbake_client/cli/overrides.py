"""`--set key=value`: config overrides of a submission and parameters of a query or render, as a dict."""

from __future__ import annotations

from typing import Annotated, Any

import typer
import yaml

from neuralbake_client.cli.remote import USAGE, exit_with

SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="key=value (a YAML value: 32, 0.5, true, [3, 12]; a.b=1 nests); repeat."),
]


def parse_sets(items: list[str]) -> dict[str, Any]:
    """`key=value` overrides -> a config dict; values are YAML scalars (`32`, `0.5`, `true`), dotted keys
    nest (`a.b=1` -> {"a": {"b": 1}})."""
    config: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            exit_with(USAGE, f"error: --set: {item!r} is not key=value")
        try:
            value = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError:
            value = raw
        *parents, leaf = key.strip().split(".")
        node = config
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                exit_with(USAGE, f"error: --set: {key} conflicts with an earlier value")
        node[leaf] = value
    return config
