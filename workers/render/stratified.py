"""Padded stratified samples per pixel (`RenderSettings.sampler`): the pixel jitter and the first surface
vertex's uniforms (light selection, light sample, BSDF sample, lobe, roulette) of a pixel's samples in one
render item lie in strata, a jittered grid per pair of dimensions and 1-D strata for the single ones, their
order shuffled per pixel and per group so that the groups stay independent ("padding", Kollig and Keller
2002; PBRT's StratifiedSampler). Deeper vertices draw independent uniforms: on prt's 48^2 far view of
env_lit_objects (depth 8, against a 4096-spp truth) stratifying the first vertex took 16 spp from 26.3 to
28.8 dB and all vertices to 28.9, for the cost of building one vertex's table."""

from __future__ import annotations

import math

import numpy as np

# The first vertex's uniforms in `wavefront.vertex_uniforms`' order, grouped into strata: 1-D or 2-D.
VERTEX_GROUPS = ((0,), (1, 2), (3, 4), (5,), (6,))


def grid(n: int) -> tuple[int, int]:
    """The most nearly square a x b = n grid (a <= b)."""
    a = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    return a, n // a


def stratified(rng: np.random.Generator, pixels: int, spp: int, dims: int) -> np.ndarray:
    """(pixels * spp, dims) uniforms, pixel-major: each pixel's `spp` rows take one stratum each of a
    1-D (dims 1) or a ~square 2-D (dims 2) grid of `spp` strata, in an order shuffled per pixel."""
    order = rng.permuted(np.broadcast_to(np.arange(spp), (pixels, spp)), axis=1).reshape(-1)
    if dims == 1:
        cells, sizes = order[:, None], (spp,)
    else:
        a, b = grid(spp)
        cells, sizes = np.stack([order % a, order // a], axis=1), (a, b)
    return (cells + rng.random((len(order), dims))) / np.asarray(sizes, np.float64)


class StratifiedUniforms:
    """A render item's random stream for `pixels` pixels of `spp` paths each (path i is sample i % spp of
    pixel i // spp): stratified camera jitter and first-vertex uniforms; everything else, independent
    uniforms from `rng` (it answers as the Generator does)."""

    def __init__(self, rng: np.random.Generator, pixels: int, spp: int):
        self.rng, self.pixels, self.spp = rng, pixels, spp

    def __getattr__(self, name: str):
        return getattr(self.rng, name)

    def jitter(self) -> np.ndarray:
        return stratified(self.rng, self.pixels, self.spp, 2)

    def first_vertex(self, paths: np.ndarray) -> np.ndarray:
        """(len(paths), 7) uniforms of the paths (indices into the item's) at their first surface vertex."""
        columns = [stratified(self.rng, self.pixels, self.spp, len(group)) for group in VERTEX_GROUPS]
        return np.concatenate(columns, axis=1)[paths]


def surface_uniforms(
    rng: np.random.Generator | StratifiedUniforms, paths: np.ndarray, segment: int
) -> np.ndarray:
    """The (len(paths), 7) uniforms of a surface vertex: stratified at a `StratifiedUniforms`' first."""
    if segment == 1 and isinstance(rng, StratifiedUniforms):
        return rng.first_vertex(paths)
    return rng.random((len(paths), 7))
