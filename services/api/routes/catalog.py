"""`/v1/kinds` and `/v1/scenes`: what a job can be made of (the registered kinds with their presets'
resolved configs and their config's JSON schema, the built-in scenes), so a client offers real choices
and checks overrides instead of hard-coding them."""

from __future__ import annotations

import inspect
from typing import Any

from fastapi import APIRouter, Depends
from pydantic import BaseModel, Field

from services.jobs.errors import KindNotFound
from services.platform.auth import require
from services.platform.problems import PROBLEM_RESPONSES
from workers.models.registry import PRESET_NAMES, UnknownKind, get_kind, kind_names
from workers.runtime.contract import Kind
from workers.scene.generators.builtin import BUILTIN_SCENES

router = APIRouter(
    prefix="/v1",
    tags=["catalog"],
    dependencies=[Depends(require("read"))],
    responses={s: PROBLEM_RESPONSES[s] for s in (401, 403)},
)


class PresetView(BaseModel):
    name: str
    config: dict[str, Any] = Field(description="The config this preset resolves to, without overrides.")


class KindView(BaseModel):
    name: str
    trains: bool = Field(description="Whether jobs train a model (and ship a speed-against-error report).")
    presets: list[PresetView] = Field(description=f"In the order {', '.join(PRESET_NAMES)}.")
    example_scene: str = Field(description="The built-in scene the kind's smallest job uses.")
    example_overrides: dict[str, Any]
    config_schema: dict[str, Any] = Field(
        description="The config's JSON schema: every parameter's type, bounds, default and description "
        "(docs/kinds/<kind>.md is made from it)."
    )

    @classmethod
    def of(cls, kind: Kind) -> KindView:
        presets = [
            PresetView(name=name, config=kind.resolve_config(name, {}).model_dump(mode="json"))
            for name in PRESET_NAMES
        ]
        return cls(
            name=kind.name,
            trains=kind.method is not None,
            presets=presets,
            example_scene=kind.example.scene,
            example_overrides=kind.example.overrides,
            config_schema=kind.config_model.model_json_schema(),
        )


class KindList(BaseModel):
    items: list[KindView]


class SceneView(BaseModel):
    name: str = Field(description="What a job's `scene` names.")
    description: str


class SceneList(BaseModel):
    items: list[SceneView]


@router.get("/kinds", response_model=KindList)
def list_kinds() -> KindList:
    """The registered model kinds, by name."""
    return KindList(items=[KindView.of(get_kind(name)) for name in kind_names()])


@router.get("/kinds/{kind}", response_model=KindView, responses={404: PROBLEM_RESPONSES[404]})
def get_kind_view(kind: str) -> KindView:
    try:
        return KindView.of(get_kind(kind))
    except UnknownKind as error:
        raise KindNotFound(str(error)) from None


@router.get("/scenes", response_model=SceneList)
def list_scenes() -> SceneList:
    """The built-in scenes, by name, each with the first line of its description."""
    return SceneList(
        items=[
            SceneView(name=name, description=(inspect.getdoc(BUILTIN_SCENES[name]) or "").splitlines()[0])
            for name in sorted(BUILTIN_SCENES)
        ]
    )
