"""The uniform baseline a job trains beside active exploration at equal wall-clock time (Table 5.3).

Same network (and initial weights), store, reuse, sampler actors and schedule of the learning rate; large
steps only, every proposal accepted, no resolution schedule unless the config asks for one. Equal time:
active exploration's extra cost is its targets (a per-patch backward pass of each judged proposal and
current state, `Explorer.targets`), which the baseline does not pay, so over the active run's wall-clock
training time T, of which T_f went to the targets, the baseline runs N T / (T - T_f) steps for active's N.
Both times are the explorer's own counts, checkpointed with it, so a resumed job decides the same number;
the report gives both runs' measured times beside their errors, which shows how equal they came out.
"""

from __future__ import annotations

import math

from workers.models.explore.config import UNIFORM, ExploreConfig

NAME = "uniform"  # the baseline's checkpoint sub-store


def uniform_config(config: ExploreConfig) -> ExploreConfig:
    """The config of the baseline of a run of `config`."""
    return config.model_copy(update={"exploration": UNIFORM})


def equal_time_steps(steps: int, seconds: float, target_seconds: float) -> int:
    """The steps the baseline takes in the wall-clock time active exploration took for `steps`, of which
    `target_seconds` went to its targets: N T / (T - T_f), at least N (no time measured: N)."""
    spent = seconds - target_seconds
    if steps < 1 or not math.isfinite(seconds) or seconds <= 0 or spent <= 0:
        return max(steps, 1)
    return max(steps, round(steps * seconds / spent))
