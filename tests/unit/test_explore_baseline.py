"""The uniform baseline's share of a job: its step count at equal wall-clock time, from the time active
exploration's explorer measured (all of it, and the parts spent on renders, targets and reused steps)."""

from __future__ import annotations

import pytest

from tests.unit.test_explore_model import explore_run
from workers.models.explore.baseline import equal_time_steps, uniform_config
from workers.models.explore.config import PRESETS, UNIFORM, ExploreConfig
from workers.scene.generators.builtin import get_builtin


def counts(seconds=60.0, target=15.0, render=6.0, reuse=27.0, timed_reuses=270, generated=30, reused=270):
    return {
        "seconds": seconds, "target_seconds": target, "render_seconds": render, "reuse_seconds": reuse,
        "timed_reuses": timed_reuses, "generated": generated, "reused": reused,
    }  # fmt: skip


def test_the_baseline_takes_the_steps_that_fit_active_explorations_time_without_the_chains_work():
    # a step renders 6 s / 300 and trains like a reused step, 0.1 s: 0.12 s, so 500 steps in 60 s
    assert equal_time_steps(300, counts()) == 500
    # slower reused steps: fewer steps (60 s / (0.02 + 1/6 s)), never fewer than active's
    assert equal_time_steps(300, counts(reuse=45.0)) == 321
    assert equal_time_steps(300, counts(reuse=80.0)) == 300
    # no reused step timed (a run inside its bootstrap): active's steps without their targets' time
    assert equal_time_steps(300, counts(timed_reuses=0)) == 400
    assert equal_time_steps(300, counts(target=0.0, timed_reuses=0)) == 300
    assert equal_time_steps(300, counts(seconds=0.0)) == 300  # nothing measured: the same steps
    assert equal_time_steps(300, counts(target=60.0, timed_reuses=0)) == 300  # never divides by zero
    assert equal_time_steps(0, counts(seconds=1.0)) == 1


def test_the_baseline_is_uniform_with_no_schedule_and_a_uniform_run_has_none():
    active = ExploreConfig.model_validate(PRESETS["quick"] | {"uniform_baseline": True})
    uniform = uniform_config(active)
    assert uniform.exploration == UNIFORM and not uniform.schedules_resolution
    assert active.schedules_resolution
    with pytest.raises(ValueError, match="uniform_baseline"):
        ExploreConfig.model_validate(PRESETS["quick"] | {"uniform_baseline": True, "exploration": UNIFORM})


def test_the_explorer_times_its_loop_its_renders_its_targets_and_its_reused_steps():
    active, _, _ = explore_run(get_builtin("mirror_variable"), 3, 24, bootstrap=6, spp=1)
    uniform, _, _ = explore_run(
        get_builtin("mirror_variable"), 3, 24, bootstrap=6, spp=1, exploration=UNIFORM
    )
    for explorer in active, uniform:
        c = explorer.counts
        assert 0 < c["render_seconds"] + c["target_seconds"] + c["reuse_seconds"] < c["seconds"]
        # every reused batch but one the loop stopped after was timed
        assert 0 < c["reused"] - 1 <= c["timed_reuses"] <= c["reused"]
        assert c["reuse_seconds"] > 0
    assert active.counts["target_seconds"] > 0 == uniform.counts["target_seconds"]
    assert active.statistics()["training_seconds"] == active.counts["seconds"]
