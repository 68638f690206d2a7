"""The shape registry: every shape type of the scene format has a mesh builder, and every function a table
names exists (the tables name them as strings, so nothing else would notice a typo or a missing type)."""

from __future__ import annotations

import typing

import pytest

from workers.scene.format import spec
from workers.scene.geometry.registry import ENVIRONMENT_IMAGES, SHAPE_MESHES, SHAPE_TRIANGLES, registered


def _types(union) -> set[str]:
    members = typing.get_args(typing.get_args(union)[0])
    return {member.model_fields["type"].default for member in members}


def test_every_shape_type_has_a_mesh_builder_and_counts_only_known_types():
    assert set(SHAPE_MESHES) == _types(spec.Shape)
    assert set(SHAPE_TRIANGLES) <= set(SHAPE_MESHES)
    assert set(ENVIRONMENT_IMAGES) <= _types(spec.Environment)


@pytest.mark.parametrize(
    ("table", "type_"),
    [(table, type_) for table in (SHAPE_MESHES, SHAPE_TRIANGLES, ENVIRONMENT_IMAGES) for type_ in table],
)
def test_every_registered_function_imports(table, type_):
    assert callable(registered(table, type_))


def test_an_unlisted_type_has_no_function():
    assert registered(SHAPE_TRIANGLES, "mesh") is None
    assert registered(ENVIRONMENT_IMAGES, "constant") is None
