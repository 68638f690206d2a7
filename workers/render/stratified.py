"""Padded stratified samples per pixel (`RenderSettings.sampler`): the pixel jitter and the first surface
vertex's uniforms (light selection, light sample, BSDF sample, lobe, roulette) of a pixel's samples in one
render item lie in strata, a jittered grid per pair of dimensions and 1-D strata for the single ones, their
order shuffled per pixel and per group so that the groups stay independent ("padding", Kollig and Keller
2002; PBRT's StratifiedSampler). A group's order is one random permutation of its strata, cyclically
shifted by a random amount per pixel: every pixel takes every stratum once and each sample's stratum is
uniform (a permutation per pixel and group cost 30 ms a 48^2 frame at 64 spp, a fifth of prt's direct
light). Deeper vertices draw independent uniforms: on prt's 48^2 far view of env_lit_objects under a cube
map (CPU s, one thread, PSNR against a 4096-spp truth of the same depth, medians of 3 seeds), stratifying
the first vertex took path tracing (depth 8) at 4 / 16 / 64 spp from 20.5 / 26.3 / 31.8 dB to 21.4 / 28.7
/ 35.0 and the direct light alone (depth 2) from 18.9 / 25.3 / 30.9 to 20.3 / 28.3 / 36.0, at the same
time within the machine's noise; stratifying every vertex gained 0.1-0.2 dB more (prototype, strata of
16 samples)."""

from __future__ import annotations

import math

import numpy as np

from workers.render.jit import njit

# The camera jitter, then the first vertex's uniforms in `wavefront.vertex_uniforms`' order, by group.
JITTER = ((0, 1),)
VERTEX_GROUPS = ((0,), (1, 2), (3, 4), (5,), (6,))


def grid(n: int) -> tuple[int, int]:
    """The most nearly square a x b = n grid (a <= b)."""
    a = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    return a, n // a


def stratified(
    rng: np.random.Generator, pixels: int, spp: int, groups: tuple, paths: np.ndarray | None = None
) -> np.ndarray:
    """(len(paths), dims) uniforms of `paths` (default: all, pixel-major: path i is sample i % spp of pixel
    i // spp): per group of `groups` (column indices, one or two), each pixel's samples take one stratum
    each of a 1-D or a ~square 2-D grid of `spp` strata."""
    paths = np.arange(pixels * spp) if paths is None else np.asarray(paths, np.int64)
    dims = sum(len(g) for g in groups)
    orders = np.stack([rng.permutation(spp) for _ in groups])
    shifts = rng.integers(spp, size=(len(groups), pixels))
    columns = np.full((len(groups), 2), -1)
    sizes = np.ones((len(groups), 2), np.int64)
    for g, group in enumerate(groups):
        columns[g, : len(group)] = group
        sizes[g, : len(group)] = grid(spp) if len(group) == 2 else (spp,)
    return _strata(paths, spp, orders, shifts, columns, sizes, rng.random((len(paths), dims)))


@njit(cache=True, nogil=True)
def _strata(paths, spp, orders, shifts, columns, sizes, u):
    for i in range(len(paths)):
        pixel, sample = paths[i] // spp, paths[i] % spp
        for g in range(len(orders)):
            cell = (orders[g, sample] + shifts[g, pixel]) % spp
            a = sizes[g, 0]
            first = columns[g, 0]
            if columns[g, 1] < 0:
                u[i, first] = (cell + u[i, first]) / a
            else:
                second = columns[g, 1]
                u[i, first] = (cell % a + u[i, first]) / a
                u[i, second] = (cell // a + u[i, second]) / sizes[g, 1]
    return u


class StratifiedUniforms:
    """A render item's random stream for `pixels` pixels of `spp` paths each (path i is sample i % spp of
    pixel i // spp): stratified camera jitter and first-vertex uniforms; everything else, independent
    uniforms from `rng` (it answers as the Generator does)."""

    def __init__(self, rng: np.random.Generator, pixels: int, spp: int):
        self.rng, self.pixels, self.spp = rng, pixels, spp

    def __getattr__(self, name: str):
        return getattr(self.rng, name)

    def jitter(self) -> np.ndarray:
        return stratified(self.rng, self.pixels, self.spp, JITTER)

    def first_vertex(self, paths: np.ndarray) -> np.ndarray:
        """(len(paths), 7) uniforms of the paths (indices into the item's) at their first surface vertex."""
        return stratified(self.rng, self.pixels, self.spp, VERTEX_GROUPS, paths)


def surface_uniforms(
    rng: np.random.Generator | StratifiedUniforms, paths: np.ndarray, segment: int
) -> np.ndarray:
    """The (len(paths), 7) uniforms of a surface vertex: stratified at a `StratifiedUniforms`' first."""
    if segment == 1 and isinstance(rng, StratifiedUniforms):
        return rng.first_vertex(paths)
    return rng.random((len(paths), 7))
