"""What every kind's config has, under the same names: how many sampler actors, GPUs, and, for a kind that
trains, the training loop and the report's sample counts. A kind's config subclasses one of these and adds
its method's knobs; every part is a `StrictModel`, so a misspelt key at any depth is an error naming it.

A nested part given as a dict (in a preset, an override or the constructor) changes only the keys it
names in the kind's default for that field: `{"grid": {"log2_table_size": 14}}` keeps the kind's grid
levels and resolutions, and `{"train": {"steps": 30}}` its learning rate.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field, model_validator

from workers.runtime.contract import merge_nested
from workers.runtime.training import TrainConfig
from workers.scene.format.strict import StrictModel


def results_link(kind: str, anchor: str) -> str:
    """A link from a field's description to the entry of `docs/results/<kind>.md` that chose its default,
    relative to the kinds' parameter pages (`docs/kinds/<kind>.md`) that show the descriptions."""
    return f"([results](../../docs/results/{kind}.md#{anchor}))"


class KindConfig(StrictModel):
    samplers: int = Field(
        1, ge=0, le=1024, description="Ray sampler actors making batches; 0 makes them in the driver."
    )
    num_gpus: float = Field(
        0, ge=0, le=64, description="GPUs for the driver, used when the cluster has them."
    )

    @model_validator(mode="before")
    @classmethod
    def _parts_update_the_kinds_defaults(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        given_parts = {
            name: field.default.model_dump()
            for name, field in cls.model_fields.items()
            if name in data and isinstance(field.default, BaseModel)
        }
        return merge_nested(given_parts, data)


class TrainedKindConfig(KindConfig):
    """A kind that trains a model and reports it against path tracing of one view."""

    train: TrainConfig = Field(TrainConfig(), description="The training loop: steps, Adam and checkpoints.")
    evaluation_spp: int = Field(
        16, ge=1, le=65536, description="Samples per pixel of the model's frame in the report."
    )
    reference_spp: int = Field(
        1024,
        ge=2,
        le=1 << 20,
        description="Samples per pixel of the converged path-traced image the report measures against.",
    )
    torch_threads: int | None = Field(
        None,
        ge=1,
        le=256,
        description="torch's intra-op threads while the job runs (None: the process's setting); kinds of "
        "small networks set 1, since extra threads only busy-wait on their tiny ops.",
    )

    @model_validator(mode="after")
    def _reference_converges_further(self) -> TrainedKindConfig:
        if self.reference_spp <= self.evaluation_spp:
            raise ValueError(
                f"reference_spp ({self.reference_spp}) must exceed evaluation_spp ({self.evaluation_spp}): "
                "the report measures the model's frame against it"
            )
        return self
