"""docs/kinds/: every registered kind's parameter page says what its config and presets say now, and the
tables read a config's schema right (nested parts by dotted name, a union's members, a map of parts)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from scripts.kind_docs import COMMAND, FOLDER, ROOT, pages, parameters
from workers.nn.configs import EncodingConfig, HashGridConfig
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import OptimizerConfig, TrainConfig
from workers.scene.format.strict import StrictModel


def test_every_kinds_page_is_current():
    written = pages()
    stale = [
        str(path.relative_to(ROOT))
        for path in sorted(set(written) | set(FOLDER.glob("*.md")))
        if not path.exists() or path.read_text() != written.get(path)
    ]
    assert not stale, f"{', '.join(stale)}: stale; run `{COMMAND}` and commit the pages"


class Square(StrictModel):
    type: Literal["square"] = "square"
    size: float = Field(1.0, description="side")


class Disk(StrictModel):
    type: Literal["disk"] = "disk"
    size: float = Field(1.0, description="diameter")
    segments: int = 32


class ToyConfig(TrainedKindConfig):
    encoding: EncodingConfig = HashGridConfig()
    shape: Annotated[Square | Disk, Field(discriminator="type")] = Disk()
    train: TrainConfig = TrainConfig(optimizers={"generator": OptimizerConfig()})


def rows_by_name(configs: list[dict]) -> dict:
    return {row.name: row for row in parameters(ToyConfig.model_json_schema(), configs)}


def test_rows_name_nested_parts_by_dotted_name_with_type_bounds_and_description():
    rows = rows_by_name([ToyConfig().model_dump(mode="json")])
    assert rows["evaluation_spp"].types == ["int in [1, 65536]"]
    assert rows["evaluation_spp"].description == ToyConfig.model_fields["evaluation_spp"].description
    assert rows["torch_threads"].types == ["int in [1, 256] | None"]
    assert rows["train.steps"].types[0].startswith("int") and not rows["train.steps"].only_with
    assert "train" not in rows and "encoding" not in rows


def test_a_union_lists_every_member_and_has_rows_for_the_chosen_ones_saying_which():
    grid = ToyConfig().model_dump(mode="json")
    blob = ToyConfig(encoding={"type": "one_blob"}, shape={"type": "square"}).model_dump(mode="json")
    rows = rows_by_name([grid, blob])
    assert rows["encoding.type"].types[0].startswith('"hash_grid" | "spherical_harmonics"')
    assert not rows["encoding.type"].only_with  # every member has one
    assert rows["encoding.levels"].only_with == ["encoding.type: hash_grid"]
    assert rows["encoding.n_bins"].only_with == ["encoding.type: one_blob"]
    assert not any(name.startswith("encoding.encoding") for name in rows)  # shared_inputs: not chosen
    assert "encoding.levels" not in rows_by_name([blob])
    assert not rows["shape.size"].only_with and rows["shape.size"].description == "side"  # both have one
    assert rows["shape.segments"].only_with == ["shape.type: disk"]


def test_a_map_of_parts_has_rows_for_the_keys_the_presets_give():
    rows = rows_by_name([ToyConfig().model_dump(mode="json"), {"train": {"optimizers": {"critic": {}}}}])
    assert {"train.optimizers.generator.schedule.lr", "train.optimizers.critic.eps"} <= set(rows)
    assert "train.optimizers" not in rows
    assert "train.optimizers" in rows_by_name([{"train": {"optimizers": {}}}])
