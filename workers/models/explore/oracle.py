"""The size of the step Adam would take for a gradient, without taking it (the target's second factor,
thesis Sec. 5.4: f(u) = loss(u) x ||Adam step||; with the loss alone chains stick to states the network
cannot learn, such as mirror reflections, Table 5.7).

The step is computed from the optimizer's moments as `torch.optim.Adam` would update them (momentum and
RMSprop included, bias-corrected at the next step count); with no state yet it is Adam's first step from
zero moments, which is what a real step would do. Nothing of the optimizer or the parameters changes.
Gradients come stacked, one per sample, so the steps of many patches cost one vectorised pass per
parameter.

What the factor does, measured once (mirror_variable, bench_explore's config after 1500 steps, the
last 96 stored patches): the step norm falls as the loss rises (Spearman -0.66 between them), so f
ranks patches less steeply than the loss alone; and a patch's own share of the step (its gradient
without the momentum) ranks them as the whole step does (Spearman 0.993 between the two f): one
patch's gradient is far larger than the momentum of batch means.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor


@torch.no_grad()
def adam_step_norms(adam: torch.optim.Adam, gradients: Mapping[torch.nn.Parameter, Tensor]) -> Tensor:
    """[N]: ||theta_after - theta_before|| over the parameters in `gradients` of the Adam step each of N
    samples would cause alone; `gradients` maps parameters of `adam` to their gradients [N, *shape].
    Adam moves each parameter by its own gradient only, so this is the real step's displacement of those
    parameters whatever the others' gradients are."""
    total: Tensor | None = None
    for group in adam.param_groups:
        if group.get("amsgrad") or group.get("maximize"):
            raise ValueError("the step-norm oracle models plain Adam (no amsgrad, no maximize)")
        beta1, beta2 = group["betas"]
        lr, eps, weight_decay = group["lr"], group["eps"], group["weight_decay"]
        for parameter in group["params"]:
            grad = gradients.get(parameter)
            if grad is None:
                continue
            if weight_decay:
                grad = grad + weight_decay * parameter
            state = adam.state.get(parameter, {})
            step = float(state["step"]) + 1 if state else 1.0
            zeros = torch.zeros_like(parameter)
            exp_avg = state.get("exp_avg", zeros) * beta1 + (1 - beta1) * grad
            exp_avg_sq = state.get("exp_avg_sq", zeros) * beta2 + (1 - beta2) * grad * grad
            denominator = exp_avg_sq.sqrt() / math.sqrt(1 - beta2**step) + eps
            update = (lr / (1 - beta1**step)) * exp_avg / denominator
            squares = update.square().flatten(1).sum(dim=1, dtype=torch.float64)
            total = squares if total is None else total + squares
    if total is None:
        raise ValueError("no gradient for any parameter of the optimizer")
    return total.sqrt()
