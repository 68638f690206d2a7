"""Training batches of the `prt` kind (Sec. 5): every batch draws fresh lightings from the training
distribution (the paper one, here `lightings_per_step`: one lighting's gradient pulls the whole network
towards a single sun or sky, and which lightings came first decided the result), takes each one's Haar
transform and picks its wavelets (largest + uniform), then samples an equal share of the pixels for each
from the pixel maps (an equal share each) and computes their full-lighting indirect ground truth as row . L,
the row being the mean of the pixel's nearest traced rows, as many as its object's rows choose (`data`,
`neighbours`). Rows are kept as their Haar coefficients (`TrainingSet.target_wavelets`): row . L is the dot
product of the two coefficient vectors (the transform is orthonormal), and a wavelet's transport, which
`transport_weight` supervises, is read off the row. Lightings are scaled to unit mean radiance
(`lighting.unit_mean`). With `lighting_pool` > 0 the lightings are drawn from a pool built once per job
(cube, Haar transform and ranking precomputed), so many lightings per step cost little; the wavelets and
pixels stay fresh per draw. Batch i is a pure function of (seed, i)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.models.prt.config import PrtConfig
from workers.models.prt.data import PIXEL_MAPS, TrainingSet, cached, training_set
from workers.models.prt.lighting import lighting_cube, training_lighting, unit_mean
from workers.models.prt.probe import modelled_objects
from workers.models.prt.selection import RankedWavelets, ranked_wavelets, training_selection
from workers.runtime.sources import Batch, batch_rng
from workers.runtime.threads import torch_threads
from workers.scene.portability.reference import SceneRef

POOL_STREAM = 2**41  # the pool's random stream; batch indices never reach it


@dataclass(frozen=True)
class PrtSourceConfig:
    scene: SceneRef
    prt: PrtConfig


def draw_lighting(config: PrtConfig, rng: np.random.Generator) -> RankedWavelets:
    """A fresh lighting of the training distribution, as its ranked Haar coefficients."""
    env = training_lighting(config.lighting, rng)
    with torch_threads(1):  # tiny tensors: more threads busy-wait on a loaded CPU (10-100x slower)
        return ranked_wavelets(unit_mean(lighting_cube(env, config.cube_size, config.lighting.map_width)))


def lighting_pool(config: PrtConfig, seed: int) -> list[RankedWavelets]:
    """`config.lighting_pool` training lightings, a function of (lighting config, cube size, seed), built
    once per process."""
    key = ("pool", config.lighting.model_dump_json(), config.cube_size, config.lighting_pool, seed)

    def build() -> list[RankedWavelets]:
        rng = np.random.default_rng([seed, POOL_STREAM])
        return [draw_lighting(config, rng) for _ in range(config.lighting_pool)]

    return cached(key, build)


def sample_pixels(data: TrainingSet, n: int, rng: np.random.Generator) -> np.ndarray:
    """n pixel indices, an equal share (the first map takes the remainder) from each pixel map: the draws
    of `rng.choice(P, share, p=weights)` from the set's precomputed CDFs, so a step costs O(n log P)."""
    shares = np.full(len(PIXEL_MAPS), n // len(PIXEL_MAPS))
    shares[0] += n - shares.sum()
    picks = []
    for name, share in zip(PIXEL_MAPS, shares, strict=True):
        cdf = data.map_cdfs[name]
        if cdf is None:  # a map that is zero everywhere falls back to uniform
            picks.append(rng.integers(0, len(data.rows), size=share, dtype=np.int64))
        else:
            picks.append(cdf.searchsorted(rng.random(share), side="right").astype(np.int64))
    return np.concatenate(picks)


class PrtSource:
    def __init__(self, config: PrtSourceConfig, seed: int) -> None:
        self.config = config
        self.seed = seed
        self.objects = modelled_objects(config.scene, config.prt)
        self.data = training_set(config.scene, config.prt, seed, self.objects)
        self.pool = lighting_pool(config.prt, seed) if config.prt.lighting_pool else []

    def lighting(self, rng: np.random.Generator) -> RankedWavelets:
        """A training lighting: from the pool when there is one, else a fresh one."""
        if self.pool:
            return self.pool[int(rng.integers(len(self.pool)))]
        return draw_lighting(self.config.prt, rng)

    def batch(self, index: int) -> Batch:
        """`lightings_per_step` lightings, each with its own wavelets and an equal share of the pixels:
        `wavelets` [G, K], `coefficients` [G, K, 3], pixels group after group."""
        c = self.config.prt
        rng = batch_rng(self.seed, index)
        wavelets, values, pixels, targets, transports = [], [], [], [], []
        for share in lighting_shares(c.pixels_per_step, c.lightings_per_step):
            lighting = self.lighting(rng)
            chosen = training_selection(lighting, c.train_top_wavelets, c.train_uniform_wavelets, rng)
            picked = sample_pixels(self.data, share, rng)
            rows = self.data.targets(picked)  # Haar coefficients
            targets.append(np.einsum("pkc,kc->pc", rows, lighting.coefficients.numpy()))
            wavelets.append(chosen.indices.long())
            values.append(chosen.values.float())
            pixels.append(picked)
            if c.transport_weight > 0:
                transports.append(torch.from_numpy(rows[:, chosen.indices.numpy()]).float())
        picked = np.concatenate(pixels)
        batch = self.data.inputs.take(picked).tensors(self.data.box)
        batch.update(
            wavelets=torch.stack(wavelets),
            coefficients=torch.stack(values),
            target=torch.from_numpy(np.concatenate(targets).astype(np.float32)),
        )
        if transports:
            batch["transport"] = torch.cat(transports)
        return batch


def lighting_shares(pixels: int, groups: int) -> list[int]:
    """Pixels per lighting group of a batch: equal, the first takes the remainder."""
    shares = [pixels // groups] * groups
    shares[0] += pixels - sum(shares)
    return shares
