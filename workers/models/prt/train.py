"""The `prt` loss (Sec. 5): L2 of mu-law tonemapped radiance (mu = 10, sign-extended for the negative values
early wavelet-domain predictions take) between B over the step's wavelets and the full-lighting indirect.

With `transport_weight` > 0, a term beyond the paper: the L2 of each selected wavelet's transport T_k
against the Haar transform of the pixel's row (free here, since rows are binned), relative to the batch's
mean squared target so the weight does not depend on the scene's brightness."""

from __future__ import annotations

import torch
from torch import Tensor

from workers.models.prt.network import PrtNetwork
from workers.models.prt.source import lighting_shares
from workers.nn.losses import mu_law_l2
from workers.runtime.sources import Batch


def prt_loss(model: PrtNetwork, batch: Batch, mu: float = 10.0, transport_weight: float = 0.0) -> Tensor:
    """The loss of a batch of G lightings (`source.PrtSource.batch`): pixels come group after group, each
    group lit by its own lighting through its own wavelets."""
    spatial, rest = model.pixel_features(batch)
    wavelets, coefficients = batch["wavelets"], batch["coefficients"]
    shares = lighting_shares(len(spatial), len(wavelets))
    transport = model.transport(spatial, rest, wavelets, shares)
    lighting = coefficients.repeat_interleave(torch.tensor(shares), dim=0)  # each pixel's group's [K, 3]
    prediction = (transport * lighting).sum(1)  # Eq. 3
    loss = mu_law_l2(prediction, batch["target"], mu)
    if transport_weight > 0:
        target = batch["transport"]
        loss = loss + transport_weight * ((transport - target) ** 2).mean() / target.square().mean().clamp(
            min=1e-12
        )
    return loss
