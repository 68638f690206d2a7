"""The size of the step Adam would take for a gradient, without taking it (the target's second factor,
thesis Sec. 5.4: f(u) = loss(u) x ||Adam step||; with the loss alone chains stick to states the network
cannot learn, such as mirror reflections, Table 5.7).

The step is computed from the optimizer's moments as `torch.optim.Adam` would update them (momentum and
RMSprop included, bias-corrected at the next step count); with no state yet it is Adam's first step from
zero moments, which is what a real step would do. Nothing of the optimizer or the parameters changes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch


@torch.no_grad()
def adam_step_norm(adam: torch.optim.Adam, gradients: Sequence[torch.Tensor | None]) -> float:
    """||theta_after - theta_before|| of the Adam step for `gradients` (one per parameter, in the order of
    `adam.param_groups`; None for a parameter the loss does not reach)."""
    total = 0.0
    grads = iter(gradients)
    for group in adam.param_groups:
        if group.get("amsgrad") or group.get("maximize"):
            raise ValueError("the step-norm oracle models plain Adam (no amsgrad, no maximize)")
        beta1, beta2 = group["betas"]
        lr, eps, weight_decay = group["lr"], group["eps"], group["weight_decay"]
        for parameter in group["params"]:
            grad = next(grads)
            if grad is None:
                continue
            if weight_decay:
                grad = grad + weight_decay * parameter
            state = adam.state.get(parameter, {})
            step = float(state["step"]) + 1 if state else 1.0
            exp_avg = state.get("exp_avg", torch.zeros_like(grad)) * beta1 + (1 - beta1) * grad
            exp_avg_sq = state.get("exp_avg_sq", torch.zeros_like(grad)) * beta2 + (1 - beta2) * grad * grad
            denominator = exp_avg_sq.sqrt() / math.sqrt(1 - beta2**step) + eps
            update = (lr / (1 - beta1**step)) * exp_avg / denominator
            total += float(update.double().square().sum())
    return math.sqrt(total)
