"""Which wavelets of a lighting are used: at run time the K with the largest area-weighted magnitude
(Sec. 4; one index set shared by R, G and B), in training the largest plus uniformly drawn others (Sec. 5:
150 + 150), so that every wavelet's transport is learned, not only those bright lightings excite."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.nn.haar import SparseWavelets, cubemap_wavelets, select_top_k


def wavelets_of(cube: np.ndarray) -> torch.Tensor:
    """Haar coefficients [6, R, R, 3] float64 of a cube map (no solid-angle weighting)."""
    return cubemap_wavelets(torch.as_tensor(cube, dtype=torch.float64))


def run_time_selection(cube: np.ndarray, k: int, weighting: str = "area") -> SparseWavelets:
    """The K wavelets a frame uses (scaling the map by a > 0 scales the values and keeps the indices)."""
    return select_top_k(wavelets_of(cube), k, weighting)


@dataclass(frozen=True)
class RankedWavelets:
    """A lighting's Haar coefficients [6 R^2, 3] and their indices by descending magnitude: what training
    selection reads, computed once per lighting (a pooled lighting is selected from many times)."""

    coefficients: torch.Tensor
    order: np.ndarray
    size: int


def ranked_wavelets(cube: np.ndarray) -> RankedWavelets:
    coefficients = wavelets_of(cube)
    flat = coefficients.reshape(-1, 3)
    order = torch.argsort(flat.norm(dim=-1), descending=True, stable=True).numpy()
    return RankedWavelets(flat, order, coefficients.shape[1])


def training_selection(
    ranked: RankedWavelets, top: int, uniform: int, rng: np.random.Generator
) -> SparseWavelets:
    """The `top` largest coefficients by magnitude and `uniform` others drawn without replacement."""
    largest = ranked.order[:top]
    rest = ranked.order[top:]
    drawn = rng.choice(rest, min(uniform, len(rest)), replace=False) if len(rest) else rest
    indices = torch.from_numpy(np.sort(np.concatenate([largest, drawn])))
    return SparseWavelets(indices, ranked.coefficients[indices], ranked.size)
