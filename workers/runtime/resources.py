"""Ray resource requests: ask for a GPU only when the config wants one and the cluster has one."""

from __future__ import annotations

import ray
from pydantic import BaseModel, Field


class ResourceRequest(BaseModel):
    """What one actor asks Ray for; `gpus` is a wish that falls back to CPU on a cluster without GPUs."""

    cpus: float = Field(1.0, ge=0)
    gpus: float = Field(0.0, ge=0)


def actor_options(request: ResourceRequest) -> dict[str, float]:
    """Ray `.options(...)` for an actor, with `num_gpus` dropped when the running cluster has no GPU."""
    options = {"num_cpus": request.cpus}
    if request.gpus > 0 and ray.cluster_resources().get("GPU", 0) >= request.gpus:
        options["num_gpus"] = request.gpus
    return options
