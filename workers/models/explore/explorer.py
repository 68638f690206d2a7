"""Active exploration as the training loop's batch stream (thesis Sec. 5.4-5.5, App. A.6-A.7).

Each iteration either generates or reuses. Generating (always during the bootstrap, else with probability
1 - p_s): every chain proposes a state, the proposals are rendered by the job's sampler actors
(`Renders`), each proposal is judged against its chain's current state by the target f = loss x ||Adam
step|| evaluated with the current weights (per-patch gradients of the layers, `targets`), and the batch
holds the accepted proposal, or the rejected proposal and the current state [code]: every rendered patch
is trained on at least once and long-lived states are retrained (`train_rejected`; without it a rejected
proposal is only stored, and every batch holds one patch per chain). Reusing: `chains` stored patches
drawn in proportion to their last loss (or uniformly, `reuse_draw`).

The same loop with large steps only, every proposal accepted and no resolution schedule is the uniform
baseline (Table 5.3), so both share the network, the store, reuse and the time budget.

Everything random comes from (seed, iteration), and the patches from requests that carry their seeds, so
a run is reproducible for a seed. The exploration is part of the training runtime's checkpoints (a
`ResumableStream`): the chains' states and current patches, the store (ids, requests, weights, pins), the
two loss averages and the counters go into `stream-exploration.json`, and a resumed job renders the
stored patches again from their requests, so it continues exactly as the uninterrupted one (there is no
random state to carry: each iteration's generator is seeded by (seed, iteration)). Seeking to an
iteration with no such state restarts the chains, the store and the bootstrap there.

The explorer also keeps an exponential moving average of the weights the loss is evaluated with
(`average`, checkpointed beside the exploration): at a constant or slowly decaying rate the weights
oscillate from step to step, and the average is what the job saves and measures.
"""

from __future__ import annotations

import contextlib
import copy
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import safetensors.torch
import torch
from torch import Tensor
from torch.func import functional_call, grad, vmap

from workers.models.explore.config import UNIFORM, ExploreConfig
from workers.models.explore.exploration import greedy, large_step, propose
from workers.models.explore.features import POSITION
from workers.models.explore.network import PixelGenerator
from workers.models.explore.oracle import adam_step_norms
from workers.models.explore.reuse import MovingAverage, PatchStore, reuse_probability
from workers.models.explore.source import PatchRequest, render_seed, request_for
from workers.nn.ssim import ssim_map
from workers.nn.tonemap import srgb_encode
from workers.runtime.samplers import Renders
from workers.runtime.sources import Batch
from workers.runtime.threads import torch_threads
from workers.runtime.training import Phase

PATCH_KEYS = ("features", "emission", "target")
STATE_FILE = "stream-exploration.json"  # the exploration's part of a training checkpoint
AVERAGE_FILE = "stream-average.safetensors"  # the averaged weights
COUNTS = ("proposals", "accepted", "large_steps", "generated", "reused", "chain_age", "timed_reuses")
# wall-clock seconds of the training loop between this stream's batches; of them, in the targets, in the
# patches' renders, and in the steps on reused batches (`timed_reuses` of them): what the uniform
# baseline's equal-time step count is estimated from (`baseline.equal_time_steps`)
TIMES = ("seconds", "target_seconds", "render_seconds", "reuse_seconds")
AVERAGE_WARMUP = 10  # the decay at the n-th average is min(decay, (1 + n) / (10 + n))


def patch_losses(
    model: Callable[[Tensor, Tensor], Tensor],
    batch: Batch,
    l1_weight: float,
    ssim_weight: float = 1.0,
    display: bool = False,
) -> Tensor:
    """Per patch [N]: mean over pixels of w_1 |log1p L - log1p L_ref| + w_s (1 - SSIM) ([code]: 2 and 1);
    `display`: of the sRGB images a preview shows instead of log1p radiance."""
    prediction = model(batch["features"], batch["emission"])
    target = batch["target"].clamp_min(0.0)
    if display:
        prediction, reference = srgb_encode(torch.expm1(prediction)), srgb_encode(target)
    else:
        reference = torch.log1p(target)
    loss = l1_weight * (prediction - reference).abs().mean(dim=(1, 2, 3))
    if ssim_weight:
        loss = loss + ssim_weight * (1 - ssim_map(prediction, reference)).mean(dim=(1, 2, 3))
    return loss


@dataclass
class Chain:
    state: np.ndarray | None = None
    patch_id: int | None = None  # its current state's patch in the store (pinned there)
    age: int = 0  # generations it has kept its current state


class Explorer:
    """The batch stream of active exploration (or of the uniform baseline) for one model."""

    def __init__(self, config: ExploreConfig, dimensions: int, model: PixelGenerator, seed: int) -> None:
        self.config = config
        self.state_dimensions = dimensions + 2
        self.model = model
        self.seed = seed
        self.adam: torch.optim.Adam | None = None
        self.renders: Renders | None = None
        self._threads: contextlib.ExitStack | None = None
        self.average = copy.deepcopy(model).requires_grad_(False)
        self._restart(0)

    # ------------------------------------------------------------------ wiring

    def phase(self) -> Phase:
        """The training phase of this explorer's model: its loss, its parameter groups (the grid's table at
        its own rate) and the Adam the targets read."""
        groups = self.model.parameter_groups(self.config.grid_lr_scale)
        return Phase("main", self.loss, groups, on_optimizer=self.attach)

    def attach(self, adam: torch.optim.Optimizer) -> None:
        """The trainer's Adam, whose moments the target's step norm reads (`Phase.on_optimizer`)."""
        self.adam = adam

    def open(self, renders: Renders) -> Explorer:
        """This stream over the job's renders (`Trainable.driven`); while it is open (the whole training of
        its model), torch runs `config.torch_threads` intra-op threads."""
        self.renders = renders
        self._threads = contextlib.ExitStack()
        self._threads.enter_context(torch_threads(self.config.torch_threads))
        return self

    def close(self) -> None:
        self.renders = None
        if self._threads is not None:
            self._threads.close()
            self._threads = None

    def __enter__(self) -> Explorer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Explorer:
        return self

    # ------------------------------------------------------------------ the stream

    def _restart(self, position: int) -> None:
        c = self.config
        self.position = position
        self.store = PatchStore(c.store_capacity)
        self.chains = [Chain() for _ in range(c.chains)]
        self.loss_new, self.loss_existing = MovingAverage(c.reuse_ema), MovingAverage(c.reuse_ema)
        self.generations = 0
        self.counts = dict.fromkeys(COUNTS, 0) | dict.fromkeys(TIMES, 0.0)
        self._last_batch: float | None = None
        self._last_reused = False  # whether the batch whose step the next interval times was reused
        self.average.load_state_dict(self.model.state_dict())
        self.averaged = 0

    def seek(self, index: int) -> None:
        if index != self.position:
            self._restart(index)

    def state_files(self) -> dict[str, bytes]:
        """The exploration's state for a checkpoint (`workers.runtime.training.ResumableStream`)."""
        state = {
            "position": self.position,
            "generations": self.generations,
            "averaged": self.averaged,
            "counts": self.counts,
            "loss_new": self.loss_new.value,
            "loss_existing": self.loss_existing.value,
            "chains": [
                [None if c.state is None else c.state.tolist(), c.patch_id, c.age] for c in self.chains
            ],
            "store": self.store.state(asdict),
        }
        average = safetensors.torch.save(self.average.state_dict())
        return {STATE_FILE: json.dumps(state).encode(), AVERAGE_FILE: average}

    def restore(self, files: dict[str, bytes]) -> None:
        """Return to a checkpoint's exploration state, rendering its stored patches again; a checkpoint
        without one (written before exploration was checkpointed) leaves `seek` to restart."""
        if STATE_FILE not in files:
            return
        if self.renders is None:
            raise RuntimeError("the explorer restores through `open(renders)`: it renders its store again")
        state = json.loads(files[STATE_FILE])
        self._restart(state["position"])
        self.generations, self.counts = state["generations"], {**self.counts, **state["counts"]}
        self.averaged = state["averaged"]
        self.average.load_state_dict(safetensors.torch.load(files[AVERAGE_FILE]))
        self.loss_new.value, self.loss_existing.value = state["loss_new"], state["loss_existing"]
        for chain, (chain_state, patch_id, *age) in zip(self.chains, state["chains"], strict=True):
            chain.state = None if chain_state is None else np.array(chain_state, dtype=np.float64)
            chain.patch_id, chain.age = patch_id, (age or [0])[0]
        self.store.restore(state["store"], _request, self.renders.map)

    def reuse_probability(self) -> float:
        """p_s now; both averages start from the fresh patches' one at the end of the bootstrap."""
        new = self.loss_new.value
        if new is None:
            return 0.0
        existing = self.loss_existing.value if self.loss_existing.value is not None else new
        return reuse_probability(existing, new, self.config.reuse_beta)

    def __next__(self) -> Batch:
        now = time.perf_counter()
        if self._last_batch is not None:  # a resumed stream counts from its first batch again
            self.counts["seconds"] += now - self._last_batch
            if self._last_reused:
                self.counts["reuse_seconds"] += now - self._last_batch
                self.counts["timed_reuses"] += 1
        self._last_batch = now
        rng = np.random.default_rng([self.seed, self.position, 1])
        bootstrapping = self.generations < self.config.bootstrap or len(self.store) == 0
        self._last_reused = not bootstrapping and rng.random() < self.reuse_probability()
        batch = self._reuse(rng) if self._last_reused else self._generate(rng)
        self.position += 1
        return batch

    def _generate(self, rng: np.random.Generator) -> Batch:
        c = self.config
        if self.renders is None:
            raise RuntimeError("the explorer renders through `open(renders)` before it is iterated")
        uniform = c.exploration == UNIFORM
        current = np.array(
            [
                chain.state if chain.state is not None else np.zeros(self.state_dimensions)
                for chain in self.chains
            ]
        )
        states, large = propose(rng, current, c.large_step_probability, c.small_step_min, c.small_step_max)
        fresh = np.array([uniform or chain.state is None for chain in self.chains])
        states = np.where(fresh[:, None], large_step(rng, current.shape), states)
        large = large | fresh
        resolution = c.resolution(self.position)
        requests = [
            request_for(state, resolution, c.patch, render_seed(self.seed, self.position, k))
            for k, state in enumerate(states)
        ]
        started = time.perf_counter()
        patches = self.renders.map(requests)
        self.counts["render_seconds"] += time.perf_counter() - started
        ids = [
            self.store.add(patch, is_large, request=request)
            for patch, is_large, request in zip(patches, large.tolist(), requests, strict=True)
        ]
        judged = [k for k, chain in enumerate(self.chains) if not uniform and chain.patch_id is not None]
        currents = [self.store.patches[self.chains[k].patch_id] for k in judged]
        values = np.zeros(0)
        if judged:
            started = time.perf_counter()
            values = self.targets([patches[k] for k in judged] + currents)
            self.counts["target_seconds"] += time.perf_counter() - started
        accepted = {k: bool(greedy(values[i], values[len(judged) + i])) for i, k in enumerate(judged)}
        self.counts["proposals"] += len(judged)
        self.counts["accepted"] += sum(accepted.values())
        self.counts["large_steps"] += int(large.sum())
        members: list[tuple[int, Batch, bool]] = []
        for k, chain in enumerate(self.chains):
            members.append((ids[k], patches[k], bool(large[k])))
            if accepted.get(k, True):
                if chain.patch_id is not None:
                    self.store.unpin(chain.patch_id)
                chain.state, chain.patch_id, chain.age = states[k], ids[k], 0
                self.store.pin(ids[k])
            else:
                chain.age += 1
                current = chain.patch_id
                if not c.train_rejected:
                    members.pop()  # stored for reuse, not trained on now
                members.append((current, self.store.patches[current], self.store.large[current]))
        self.generations += 1
        self.counts["generated"] += 1
        self.counts["chain_age"] += sum(chain.age for chain in self.chains)
        return _stack(members, reused=False)

    def _reuse(self, rng: np.random.Generator) -> Batch:
        ids = self.store.draw(rng, self.config.chains, by_loss=self.config.reuse_draw == "loss")
        self.counts["reused"] += 1
        return _stack([(i, self.store.patches[i], self.store.large[i]) for i in ids], reused=True)

    # ------------------------------------------------------------------ the target and the loss

    def targets(self, patches: list[Batch]) -> np.ndarray:
        """f(u) = loss(u) x ||Adam step of the layers for u's gradient|| of each patch with the current
        weights (Sec. 5.4), the loss taken in `target_space`; the loss alone before the trainer's Adam
        is attached.

        The step is that of the layers' weights (`PixelGenerator.layers`: the thesis's network); the hash
        grid's table, our addition, is held fixed and its features are inputs here. Its autograd Function
        (Numba kernels) cannot be vmapped, and its dense step norm over ~2.6e5 entries, of which a patch
        touches a few thousand, was a third of the target's cost. With the grid's features fixed, the
        per-patch gradients of all patches come from one `vmap`ped backward pass instead of one pass per
        patch (the authors' code): 16 patches of 16^2 took 46 ms of CPU, now 14 ms (bench's 64 x 3
        network with the grid; 68 -> 37 ms at the default 128 x 4; explore6). One pass per patch had
        made the targets ~25% of an active run's training CPU, and active got 0.65x uniform's steps."""
        device = next(self.model.parameters()).device
        c = self.config
        batch = {k: torch.stack([patch[k] for patch in patches]).to(device) for k in PATCH_KEYS}
        display = c.target_space == "display"
        if self.adam is None:
            with torch.no_grad():
                losses = patch_losses(self.model, batch, c.loss_l1_weight, c.loss_ssim_weight, display)
            return losses.double().cpu().numpy()
        with torch.no_grad():
            encoded = self.model.encode_position(batch["features"][..., POSITION])
        layers = self.model.layers()

        def loss_of(weights: dict[str, Tensor], encoded: Tensor, one: Batch) -> tuple[Tensor, Tensor]:
            def network(features: Tensor, emission: Tensor) -> Tensor:
                return functional_call(self.model, weights, (features, emission), {"encoded": encoded[None]})

            single = {k: one[k][None] for k in PATCH_KEYS}
            loss = patch_losses(network, single, c.loss_l1_weight, c.loss_ssim_weight, display)[0]
            return loss, loss.detach()

        weights = {name: p.detach() for name, p in layers.items()}
        gradients, losses = vmap(grad(loss_of, has_aux=True), in_dims=(None, 0, 0))(weights, encoded, batch)
        norms = adam_step_norms(self.adam, {layers[name]: g for name, g in gradients.items()})
        return (losses.double() * norms).cpu().numpy()

    def loss(self, model: PixelGenerator, batch: Batch) -> Tensor:
        """The training loss (the phase's); it writes each patch's loss back as its reuse weight and feeds
        the large-step patches' mean to the average of fresh or of reused patches. The weights it is
        called with (those of the previous steps) join the weights' moving average."""
        self._accumulate(model)
        per_patch = patch_losses(model, batch, self.config.loss_l1_weight, self.config.loss_ssim_weight)
        values = per_patch.detach().float().cpu().numpy()
        for patch_id, value in zip(batch["patch_id"].tolist(), values, strict=True):
            self.store.set_weight(patch_id, float(value))
        large = batch["large"].cpu().numpy() > 0.5
        if large.any():
            average = self.loss_existing if bool(batch["reused"][0]) else self.loss_new
            average.update(float(values[large].mean()))
        return per_patch.mean()

    @torch.no_grad()
    def _accumulate(self, model: PixelGenerator) -> None:
        decay = min(self.config.average_decay, (1 + self.averaged) / (AVERAGE_WARMUP + self.averaged))
        for mean, weight in zip(self.average.parameters(), model.parameters(), strict=True):
            mean.lerp_(weight.detach(), 1 - decay)
        self.averaged += 1

    def statistics(self) -> dict[str, float]:
        proposals = max(self.counts["proposals"], 1)
        steps = max(self.counts["generated"] + self.counts["reused"], 1)
        return {
            "acceptance_rate": self.counts["accepted"] / proposals,
            "large_step_fraction": self.counts["large_steps"]
            / max(self.counts["generated"] * len(self.chains), 1),
            "generated_fraction": self.counts["generated"] / steps,
            "patches_rendered": float(self.counts["generated"] * len(self.chains)),
            "final_reuse_probability": self.reuse_probability(),
            "final_resolution": float(self.config.resolution(self.position)),
            # generations a chain had kept its state, averaged over chains and generations
            "mean_chain_age": self.counts["chain_age"] / max(self.counts["generated"] * len(self.chains), 1),
            "stored_patches": float(len(self.store)),
            "training_seconds": self.counts["seconds"],
            "target_seconds": self.counts["target_seconds"],
        }


def _request(fields: dict) -> PatchRequest:
    return PatchRequest(**{**fields, "v": tuple(fields["v"])})


def _stack(members: list[tuple[int, Batch, bool]], reused: bool) -> Batch:
    batch = {k: torch.stack([patch[k] for _, patch, _ in members]) for k in PATCH_KEYS}
    batch["patch_id"] = torch.tensor([i for i, _, _ in members], dtype=torch.int64)
    batch["large"] = torch.tensor([float(large) for _, _, large in members])
    batch["reused"] = torch.full((len(members),), float(reused))
    return batch
