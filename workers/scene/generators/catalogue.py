"""Every procedural generator by name, and how a `procedural` shape is built and counted from them: the
tables of `procedural` and `mesoscale` joined (`workers.scene.geometry.registry` names the two functions)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators import mesoscale, procedural
from workers.scene.generators.procedural import parse_params
from workers.scene.geometry.mesh import MeshData

GENERATORS = procedural.GENERATORS | mesoscale.GENERATORS


def generate(name: str, params: dict[str, Any], field: str, max_triangles: int | None = None) -> MeshData:
    """The mesh of generator `name` with `params`; errors name `field.generator` or `field.params.<key>`.

    A generator that would make more than `max_triangles` is refused before it runs.
    """
    params_model, fn = GENERATORS[_known(name, field)]
    parsed = parse_params(params_model, params, f"{field}.params")
    if max_triangles is not None and parsed.triangles() > max_triangles:
        raise SceneError(
            f"{field}.params",
            f"{name} makes {parsed.triangles():,} triangles with these parameters, "
            f"over the limit of {max_triangles:,}",
        )
    return fn(parsed)


def generated_triangles(name: str, params: dict[str, Any], field: str) -> int:
    """What `generate(name, params, field)` would make, without making it."""
    params_model, _ = GENERATORS[_known(name, field)]
    return parse_params(params_model, params, f"{field}.params").triangles()


def procedural_mesh(shape: spec.ProceduralShape, field: str, base_dir: Path | None) -> MeshData:
    """The mesh of a `procedural` shape (`workers.scene.geometry.registry`)."""
    return generate(shape.generator, shape.params, field)


def procedural_triangles(shape: spec.ProceduralShape, field: str) -> int:
    """The triangles a `procedural` shape makes, from its parameters (`workers.scene.geometry.registry`)."""
    return generated_triangles(shape.generator, shape.params, field)


def _known(name: str, field: str) -> str:
    if name not in GENERATORS:
        raise SceneError(
            f"{field}.generator",
            f"unknown procedural generator {name!r}; known: {', '.join(sorted(GENERATORS))}",
        )
    return name
