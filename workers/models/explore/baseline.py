"""The uniform baseline a job trains beside active exploration at equal wall-clock time (Table 5.3).

Same network (and initial weights), store, reuse, sampler actors and schedule of the learning rate; large
steps only, every proposal accepted, no resolution schedule unless the config asks for one. Equal time:
the baseline's step is active exploration's without the chains' work, so its cost is estimated from the
parts of active's wall-clock time its explorer measured (`Explorer.counts`, checkpointed with it, so a
resumed job decides the same number): a step on a reused batch costs what active's reused steps cost
(the same `chains` stored patches), and renders cost what active's did per step (the same patches per
generation, at the same generation rate). The chains' own work, the targets' per-patch backward passes
and the training rows of rejected proposals (batches of up to 2 `chains` patches), is what the baseline
spends on more steps (charging the targets alone, N T / (T - T_f), left the rows out: 1-2% fewer steps in
`quick`). The baseline generated as many batches as active in its steps (81 / 80, 78 / 78 in `quick`
jobs of 3000 steps, seeds 5 / 6); its measured time was 1.07 / 0.88 of active's there, with a benchmark
loading the 2-core machine: the noise of the step times themselves (a reused step 3.1-3.8 ms between
runs). The report gives both runs' measured times beside their errors.
"""

from __future__ import annotations

import math

from workers.models.explore.config import UNIFORM, ExploreConfig

NAME = "uniform"  # the baseline's checkpoint sub-store


def uniform_config(config: ExploreConfig) -> ExploreConfig:
    """The config of the baseline of a run of `config`."""
    return config.model_copy(update={"exploration": UNIFORM})


def equal_time_steps(steps: int, counts: dict[str, float]) -> int:
    """The steps the baseline takes in the wall-clock time T active exploration took for `steps`, from
    its explorer's `counts`: T / (renders a step + a reused step), at least `steps`. Without a timed
    reused step, N T / (T - T_f) for T_f the targets' time; nothing measured: N."""
    seconds = counts["seconds"]
    if steps < 1 or not math.isfinite(seconds) or seconds <= 0:
        return max(steps, 1)
    if counts.get("timed_reuses", 0) > 0:
        batches = max(counts["generated"] + counts["reused"], 1)
        per_step = counts["render_seconds"] / batches + counts["reuse_seconds"] / counts["timed_reuses"]
        return max(steps, round(seconds / per_step))
    spent = seconds - counts["target_seconds"]
    return max(steps, round(steps * seconds / spent)) if spent > 0 else steps
