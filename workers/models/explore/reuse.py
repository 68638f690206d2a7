"""Self-tuning sample reuse (thesis Sec. 5.5.1, App. A.7) and the bounded store of rendered patches.

After the bootstrap a step reuses stored patches with probability p_s = sigmoid(L_exist - L_new + beta)
(Eq. 5.4; beta = 4.6 gives 0.99 for equal losses), both losses moving averages over large-step patches
only (small steps are biased towards high loss). Reused patches are drawn in proportion to their last loss,
refreshed whenever they are trained (or uniformly: `ExploreConfig.reuse_draw`). The store evicts the
oldest patch no chain currently sits on, so a chain's current sample is never lost.

Each patch keeps the request it was rendered from, so the store's state (`state`, `restore`) is a few
numbers per patch: a resumed job renders the same patches again instead of checkpointing their pixels.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from workers.runtime.sources import Batch

MAX_LOGIT = 30.0  # sigmoid(30) = 1 - 9e-14: p_s stays inside (0, 1) however far apart the losses are


def reuse_probability(loss_existing: float, loss_new: float, beta: float) -> float:
    """p_s of Eq. 5.4, in the open interval (0, 1) for any finite or infinite losses (NaN: generate)."""
    x = loss_existing - loss_new + beta
    if np.isnan(x):
        return 1.0 / (1.0 + np.exp(MAX_LOGIT))
    x = float(np.clip(x, -MAX_LOGIT, MAX_LOGIT))
    return 1.0 / (1.0 + np.exp(-x))


class MovingAverage:
    """An exponential moving average that starts at its first value."""

    def __init__(self, decay: float) -> None:
        self.decay = decay
        self.value: float | None = None

    def update(self, x: float) -> None:
        self.value = x if self.value is None else self.decay * self.value + (1 - self.decay) * x


class PatchStore:
    """Rendered patches by id, with their last loss, whether a large step made them and pins (chains)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"a store holds at least one patch, got capacity {capacity}")
        self.capacity = capacity
        self.patches: OrderedDict[int, Batch] = OrderedDict()
        self.weights: dict[int, float] = {}
        self.large: dict[int, bool] = {}
        self.pins: dict[int, int] = {}
        self.requests: dict[int, Any] = {}
        self.next_id = 0

    def __len__(self) -> int:
        return len(self.patches)

    def add(self, patch: Batch, large: bool, weight: float = 1.0, request: Any = None) -> int:
        """Store a patch (rendered from `request`), evicting the oldest unpinned ones beyond capacity;
        returns its id."""
        patch_id = self.next_id
        self.next_id += 1
        self.patches[patch_id], self.weights[patch_id], self.large[patch_id] = patch, weight, large
        self.requests[patch_id] = request
        for old in list(self.patches):
            if len(self.patches) <= self.capacity:
                break
            if self.pins.get(old, 0) == 0 and old != patch_id:
                del self.patches[old], self.weights[old], self.large[old], self.requests[old]
        return patch_id

    def pin(self, patch_id: int) -> None:
        self.pins[patch_id] = self.pins.get(patch_id, 0) + 1

    def unpin(self, patch_id: int) -> None:
        self.pins[patch_id] -= 1
        if self.pins[patch_id] == 0:
            del self.pins[patch_id]

    def set_weight(self, patch_id: int, loss: float) -> None:
        if patch_id in self.weights:
            self.weights[patch_id] = loss if np.isfinite(loss) and loss > 0 else 0.0

    def draw(self, rng: np.random.Generator, n: int, by_loss: bool = True) -> list[int]:
        """n ids with replacement, in proportion to their last loss (uniformly when every weight is 0, or
        when not `by_loss`)."""
        ids = np.fromiter(self.patches, np.int64, len(self.patches))
        weights = np.array([self.weights[i] for i in ids])
        total = weights.sum()
        p = weights / total if by_loss and total > 0 else None
        return [int(i) for i in rng.choice(ids, size=n, replace=True, p=p)]

    def state(self, encode_request: Callable[[Any], Any]) -> dict:
        """Everything but the pixels, JSON-ready: ids in storage order, their requests (as
        `encode_request` writes them), weights, step kinds and pins."""
        return {
            "next_id": self.next_id,
            "patches": [
                [i, encode_request(self.requests[i]), self.weights[i], self.large[i]] for i in self.patches
            ],
            "pins": [[i, n] for i, n in self.pins.items()],
        }

    def restore(
        self,
        state: dict,
        decode_request: Callable[[Any], Any],
        render: Callable[[Sequence[Any]], list[Batch]],
    ) -> None:
        """Return to `state`, rendering every stored patch again from its request (in one `render` call)."""
        requests = [decode_request(encoded) for _, encoded, _, _ in state["patches"]]
        patches = render(requests)
        self.patches, self.weights, self.large, self.requests = OrderedDict(), {}, {}, {}
        for (i, _, weight, large), request, patch in zip(state["patches"], requests, patches, strict=True):
            self.patches[i], self.weights[i], self.large[i], self.requests[i] = patch, weight, large, request
        self.pins = {i: n for i, n in state["pins"]}
        self.next_id = state["next_id"]
