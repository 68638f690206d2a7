"""The loss of one LSNIF object (Sec. 5.3); the shared pipeline trains each object with it (Adam on the
grid and the MLP together, the paper's joint optimisation).

Occlusion is a binary cross-entropy on every ray; distance (MAE after a sigmoid), normal (cosine),
albedo (relative L2 after a sigmoid) and material (cross-entropy) count only where the reference ray
hits, so the network spends nothing on what a miss would have hit.
"""

from __future__ import annotations

import torch
from torch import Tensor

from workers.models.lsnif.network import OUTPUTS_BEFORE_MATERIALS, LsnifObject
from workers.nn.losses import (
    binary_cross_entropy,
    categorical_cross_entropy,
    cosine_similarity_loss,
    mae,
    relative_l2,
)
from workers.runtime.sources import Batch


def lsnif_loss(model: LsnifObject, batch: Batch) -> Tensor:
    raw = model(batch["points"], batch["valid"])
    loss = binary_cross_entropy(raw[:, 0], batch["hit"])
    hit = batch["hit"] > 0.5
    if bool(hit.any()):
        raw = raw[hit]
        loss = loss + mae(torch.sigmoid(raw[:, 1]), batch["distance"][hit])
        loss = loss + cosine_similarity_loss(raw[:, 2:5], batch["normal"][hit])
        loss = loss + relative_l2(torch.sigmoid(raw[:, 5:8]), batch["albedo"][hit])
        loss = loss + categorical_cross_entropy(raw[:, OUTPUTS_BEFORE_MATERIALS:], batch["material"][hit])
    return loss
