"""The joint objective of both networks (Sec. 4.2-4.3): BCE on every visibility pair plus the noise-to-noise
relative L2 (Lehtinen et al. 2018) on the appearance estimates, which stays unbiased on one-sample
Monte Carlo targets. Adam at the paper's 0.005 on both networks and their grids."""

from __future__ import annotations

import statistics
import time

from torch import Tensor

from workers.models.lod.networks import LodNetworks
from workers.nn.losses import binary_cross_entropy, relative_l2
from workers.runtime.sources import Batch


def lod_loss(model: LodNetworks, batch: Batch) -> Tensor:
    logits = model.visibility(batch["vis_p_o"], batch["vis_p_i"])
    loss = binary_cross_entropy(logits, batch["vis_label"])
    if len(batch["app_value"]):
        phi = model.appearance(batch["app_centre"], batch["app_wo"], batch["app_wi"])
        loss = loss + relative_l2(phi, batch["app_value"])
    return loss


def per_network_step_seconds(model: LodNetworks, batch: Batch, repeats: int = 3) -> dict[str, float]:
    """Median forward + backward seconds of each network's own loss on one batch: the joint step split by
    network, for the per-network training times of the paper's Table 1."""
    parts = {
        "visibility": lambda: binary_cross_entropy(
            model.visibility(batch["vis_p_o"], batch["vis_p_i"]), batch["vis_label"]
        ),
        "appearance": lambda: relative_l2(
            model.appearance(batch["app_centre"], batch["app_wo"], batch["app_wi"]), batch["app_value"]
        ),
    }
    seconds = {}
    for name, loss in parts.items():
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            loss().backward()
            times.append(time.perf_counter() - start)
        model.zero_grad(set_to_none=True)
        seconds[name] = statistics.median(times)
    return seconds
