"""The `prt` loss (Sec. 5): L2 of mu-law tonemapped radiance (mu = 10, sign-extended for the negative values
early wavelet-domain predictions take) between B over the step's wavelets and the full-lighting indirect."""

from __future__ import annotations

from torch import Tensor

from workers.models.prt.network import PrtNetwork
from workers.nn.losses import mu_law_l2
from workers.runtime.sources import Batch


def prt_loss(model: PrtNetwork, batch: Batch, mu: float = 10.0) -> Tensor:
    prediction = model(batch, batch["wavelets"], batch["coefficients"])
    return mu_law_l2(prediction, batch["target"], mu)
