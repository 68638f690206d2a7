"""The job state machine: exactly the allowed transitions, final states final, retries only from RUNNING."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.jobs.states import TERMINAL, TRANSITIONS, InvalidTransition, JobState, check_transition

ALLOWED = {
    ("QUEUED", "RUNNING"),
    ("QUEUED", "CANCELLED"),
    ("QUEUED", "FAILED"),
    ("RUNNING", "SUCCEEDED"),
    ("RUNNING", "FAILED"),
    ("RUNNING", "CANCELLED"),
    ("RUNNING", "QUEUED"),
}


@given(st.sampled_from(list(JobState)), st.sampled_from(list(JobState)))
def test_only_the_listed_transitions_are_allowed(current, target):
    if (current.value, target.value) in ALLOWED:
        check_transition("job-1", current, target)
    else:
        with pytest.raises(
            InvalidTransition, match=f"job job-1 is {current.value}; it cannot become {target.value}"
        ):
            check_transition("job-1", current, target)


def test_final_states_have_no_way_out():
    assert {JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED} == TERMINAL
    assert all(not TRANSITIONS[state] for state in TERMINAL)
    assert all(state.terminal == (state in TERMINAL) for state in JobState)


@given(st.lists(st.sampled_from(list(JobState)), max_size=12))
def test_every_walk_through_the_machine_ends_at_most_once(walk):
    state, finished = JobState.QUEUED, 0
    for target in walk:
        try:
            check_transition("job-1", state, target)
        except InvalidTransition:
            continue
        state = target
        finished += state.terminal
    assert finished <= 1
