"""The uniform baseline's share of a job: its step count at equal wall-clock time, from the time active
exploration's explorer measured (all of it, and the part spent on its targets)."""

from __future__ import annotations

import pytest

from tests.unit.test_explore_model import explore_run
from workers.models.explore.baseline import equal_time_steps, uniform_config
from workers.models.explore.config import PRESETS, UNIFORM, ExploreConfig
from workers.scene.builtin import get_builtin


def test_the_baseline_takes_the_steps_active_exploration_would_without_its_targets():
    assert equal_time_steps(300, 60.0, 15.0) == 400  # 300 steps in 45 s of the 60 were not targets
    assert equal_time_steps(300, 60.0, 0.0) == 300
    assert equal_time_steps(300, 0.0, 0.0) == 300  # nothing measured: the same steps
    assert equal_time_steps(300, 60.0, 60.0) == 300  # a degenerate measurement never divides by zero
    assert equal_time_steps(0, 1.0, 0.5) == 1


def test_the_baseline_is_uniform_with_no_schedule_and_a_uniform_run_has_none():
    active = ExploreConfig.model_validate(PRESETS["quick"] | {"uniform_baseline": True})
    uniform = uniform_config(active)
    assert uniform.exploration == UNIFORM and not uniform.schedules_resolution
    assert active.schedules_resolution
    with pytest.raises(ValueError, match="uniform_baseline"):
        ExploreConfig.model_validate(PRESETS["quick"] | {"uniform_baseline": True, "exploration": UNIFORM})


def test_the_explorer_times_its_loop_and_its_targets():
    active, _, _ = explore_run(get_builtin("mirror_variable"), 3, 12, bootstrap=12, spp=1)
    uniform, _, _ = explore_run(
        get_builtin("mirror_variable"), 3, 12, bootstrap=12, spp=1, exploration=UNIFORM
    )
    assert 0 < active.counts["target_seconds"] < active.counts["seconds"]
    assert uniform.counts["target_seconds"] == 0 < uniform.counts["seconds"]
    assert active.statistics()["training_seconds"] == active.counts["seconds"]
