"""The joint objective of both networks (Sec. 4.2-4.3): BCE on every visibility pair plus the noise-to-noise
relative L2 (Lehtinen et al. 2018) on the appearance estimates, which stays unbiased on one-sample
Monte Carlo targets (for the log output in the form `positive_relative_l2`). Adam at the paper's 0.005 on
both networks and their grids."""

from __future__ import annotations

import statistics
import time

from torch import Tensor

from workers.models.lod.networks import LodNetworks
from workers.nn.losses import binary_cross_entropy, relative_l2
from workers.runtime.sources import Batch

RELATIVE_SCALE = 0.1  # below it the relative L2 turns absolute: Lehtinen et al.'s eps = 0.01 is its square


def visibility_loss(model: LodNetworks, batch: Batch) -> Tensor:
    return binary_cross_entropy(model.visibility(batch["vis_p_o"], batch["vis_p_i"]), batch["vis_label"])


def positive_relative_l2(prediction: Tensor, target: Tensor, scale: float = RELATIVE_SCALE) -> Tensor:
    """(p - t)^2 / (sg(p) (sg(p) + s)): the relative L2 of a positive prediction p = exp(r).

    Lehtinen et al.'s normaliser sg(p)^2 + s^2 (s = 0.1, relative above s, absolute below) gives
    dL/dr = 2 (p - t) p / (p^2 + s^2). Throughputs are ~0.05, below s, where that gradient is ~2 p (p - t)
    / s^2: it fades with p, so once the first steps overshoot (from exp(0) = 1, 20x the targets) the pull
    back up vanishes exponentially with r, drops below Adam's eps, and phi stays 0 (a scanned asset trained
    to phi = 3e-26, every LoD black). With sg(p) (sg(p) + s) the loss is that relative L2 well above s, and
    dL/dr = 2 (p - t) / (p + s): below s, r gets the gradient a linear output gets there, a pull of 2 t / s
    that never fades however far p falls, while targets of 0 push by at most 2 p / s. The normaliser still
    depends on the prediction alone, so the expected gradient is zero exactly at p = E[t] (unbiased on
    one-sample targets)."""
    normaliser = prediction.detach() * (prediction.detach() + scale)
    return ((prediction - target) ** 2 / normaliser).mean()


def appearance_loss(model: LodNetworks, batch: Batch) -> Tensor:
    phi = model.appearance(batch["app_centre"], batch["app_wo"], batch["app_wi"])
    if model.appearance.log_output:
        return positive_relative_l2(phi, batch["app_value"])
    return relative_l2(phi, batch["app_value"], eps=RELATIVE_SCALE**2)


def lod_loss(model: LodNetworks, batch: Batch) -> Tensor:
    loss = visibility_loss(model, batch)
    if len(batch["app_value"]):
        loss = loss + appearance_loss(model, batch)
    return loss


def per_network_step_seconds(model: LodNetworks, batch: Batch, repeats: int = 3) -> dict[str, float]:
    """Median forward + backward seconds of each network's own loss on one batch: the joint step split by
    network, for the per-network training times of the paper's Table 1."""
    seconds = {}
    for name, loss in (("visibility", visibility_loss), ("appearance", appearance_loss)):
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            loss(model, batch).backward()
            times.append(time.perf_counter() - start)
        model.zero_grad(set_to_none=True)
        seconds[name] = statistics.median(times)
    return seconds
