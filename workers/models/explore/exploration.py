"""Markov chains over the state u = (v, patch position) in [0, 1)^(K + 2) (thesis Sec. 5.4).

Proposals (Eq. 5.1): with probability p_LS a large step, a fresh uniform state; otherwise a small step
that moves every coordinate by a random sign times a magnitude s2 exp(-ln(s2 / s1) xi) in [s1, s2]
(Kelemen et al.'s mutation, as the authors' code does it; the thesis text says "normal"), wrapped onto the
torus [0, 1). Both kernels are symmetric, so Metropolis-Hastings needs only the target ratio.

Acceptance: the thesis's greedy rule (Eq. 5.3) accepts a proposal iff its target is strictly higher (the
code accepts ties); a chain then sits where the network is worst until training lowers the target there.
`metropolis` (Eq. 5.2) is kept for the test harness: it samples a fixed target exactly.
"""

from __future__ import annotations

import math

import numpy as np


def large_step(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Fresh uniform states in [0, 1)."""
    return rng.random(shape)


def small_step(rng: np.random.Generator, states: np.ndarray, s1: float, s2: float) -> np.ndarray:
    """Every coordinate moved by +-[s1, s2] (log-uniform magnitude), wrapped into [0, 1)."""
    magnitude = s2 * np.exp(-math.log(s2 / s1) * rng.random(states.shape))
    sign = np.where(rng.random(states.shape) < 0.5, -1.0, 1.0)
    moved = np.mod(states + sign * magnitude, 1.0)
    return np.where(moved >= 1.0, 0.0, moved)  # mod of a tiny negative number rounds to 1.0


def propose(
    rng: np.random.Generator, states: np.ndarray, p_large: float, s1: float, s2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Proposals for chains at `states` (n, d), and which are large steps (n,) (Eq. 5.1)."""
    large = rng.random(len(states)) < p_large
    proposals = np.where(large[:, None], large_step(rng, states.shape), small_step(rng, states, s1, s2))
    return proposals, large


def greedy(target_proposal, target_current):
    """Eq. 5.3: move only to a strictly higher target (NaN never wins); elementwise on arrays."""
    return np.asarray(target_proposal) > np.asarray(target_current)


def metropolis(rng: np.random.Generator, target_proposal, target_current):
    """Eq. 5.2 with a symmetric proposal: accept with probability min(1, f(v) / f(u)) (always from a
    state of zero target); elementwise on arrays."""
    proposal, current = np.asarray(target_proposal, float), np.asarray(target_current, float)
    ratio = np.divide(proposal, current, out=np.ones_like(proposal), where=current > 0)
    return rng.random(proposal.shape) < np.minimum(ratio, 1.0)


def patch_origin(position: np.ndarray, resolution: int, patch: int) -> tuple[int, int]:
    """The patch's top-left pixel for the state's last two coordinates: always inside the R x R image
    (0 when R equals the patch), the same relative place as R grows (Sec. 5.5.2)."""
    span = resolution - patch
    x, y = (min(int(u * (span + 1)), span) for u in position)
    return x, y
