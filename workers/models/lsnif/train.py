"""Training one LSNIF object: the loss of Sec. 5.3 and the runtime's loop over an object's ray source.

Occlusion is a binary cross-entropy on every ray; distance (MAE after a sigmoid), normal (cosine),
albedo (relative L2 after a sigmoid) and material (cross-entropy) count only where the reference ray
hits, so the network spends nothing on what a miss would have hit.
"""

from __future__ import annotations

from collections.abc import Callable

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
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import BatchStream
from workers.runtime.sources import Batch
from workers.runtime.training import Progress, TrainConfig, TrainResult, train


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


def train_object(
    model: LsnifObject,
    batches: BatchStream,
    config: TrainConfig,
    checkpoints: CheckpointStore | None = None,
    on_progress: Callable[[Progress], None] | None = None,
) -> TrainResult:
    """Adam on the grid and the MLP together (the paper's joint optimisation), resuming from checkpoints;
    the trained weights are then rounded to the artifact's float16 (`LsnifObject.round_to_storage`)."""
    result = train(model, lsnif_loss, batches, config, checkpoints, on_progress)
    model.round_to_storage()
    return result
