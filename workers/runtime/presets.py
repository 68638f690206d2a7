"""A kind's presets: one YAML file per preset in a `presets/` folder beside the kind's config
(`quick.yaml`, `default.yaml`, `paper.yaml`), each holding only the values it changes from the config's
defaults, with a comment saying why where a value needs one.

Each file is validated against the config when it is loaded, as a submission would be (strict: a count
written `"256"` is an error), so a misspelt or out-of-range value fails when the kind is imported, naming
the file and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from workers.runtime.contract import PRESET_NAMES


class PresetError(ValueError):
    """A preset file that does not parse or does not validate against its kind's config."""


def load_presets(config_model: type[BaseModel], directory: Path) -> dict[str, dict[str, Any]]:
    """Every preset of `PRESET_NAMES` from `directory/<name>.yaml`, checked against `config_model`."""
    return {name: load_preset(config_model, directory / f"{name}.yaml") for name in PRESET_NAMES}


def load_preset(config_model: type[BaseModel], path: Path) -> dict[str, Any]:
    """The values one preset file sets (an empty file sets none), once they validate."""
    try:
        values = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as error:
        raise PresetError(f"preset {path}: {error}") from error
    values = {} if values is None else values
    if not isinstance(values, dict):
        raise PresetError(f"preset {path}: expected a mapping of field names to values, got {values!r}")
    try:
        config_model.model_validate(values, strict=True)
    except ValidationError as error:
        raise PresetError(f"preset {path} does not fit {config_model.__name__}: {error}") from None
    return values
