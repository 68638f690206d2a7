"""Ground-truth transport by binning escaping paths (issue 15; beyond the paper's 4000 rendered images).

Each pixel's paths are traced once under a white cube map; every path that escapes to the environment
adds its weight (throughput times MIS weight, `workers.render.observer`) to the cube texel it leaves
through, split by how many surfaces it met first: none (the camera sees the environment), one (direct
light at the first hit) or more (indirect, what the network learns). The pixel's row T [6 R^2, 3] then
gives its radiance under any cube map L as the dot product sum_j T_j L_j (Eq. 1 discretised with the
nearest-texel convention of `lighting.CubeMapLight`), so one trace serves unlimited lightings.
Accumulation is float64 (a 1e5 sun texel times a row stays exact to float precision).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.models.prt.lighting import texels_of
from workers.render.integrator import PathTracer
from workers.render.observer import PathObserver
from workers.render.stratified import StratifiedUniforms

BACKGROUND, DIRECT, INDIRECT = 0, 1, 2  # surfaces met before the escape: 0, 1, 2 or more
MAX_PATHS_PER_TRACE = 1 << 15  # paths traced at once (rows of the chunk are dense: bound the memory)


class EscapeBinner(PathObserver):
    """Bins the escapes of `n_paths` paths by (pixel, texel, category); path i belongs to pixel
    `pixel_of_path[i]`."""

    def __init__(self, pixel_of_path: np.ndarray, size: int) -> None:
        self.pixel_of_path = pixel_of_path
        self.size = size
        self.surfaces = np.zeros(len(pixel_of_path), np.int64)
        self._events: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def on_surface(self, idx, position, normal, beta) -> None:
        self.surfaces[idx] += 1

    def on_escape(self, idx, directions, weight) -> None:
        category = np.minimum(self.surfaces[idx], INDIRECT)
        cell = self.pixel_of_path[idx] * (6 * self.size**2) + texels_of(directions, self.size)
        self._events.append((category, cell, np.asarray(weight, np.float64)))

    def rows(self, n_pixels: int, category: int) -> np.ndarray:
        """Summed weights [n_pixels, 6 R^2, 3] float64 of one category."""
        cells = n_pixels * 6 * self.size**2
        out = np.zeros((cells, 3))
        for events_category, cell, weight in self._events:
            keep = events_category == category
            if keep.any():
                for c in range(3):
                    out[:, c] += np.bincount(cell[keep], weights=weight[keep, c], minlength=cells)
        return out.reshape(n_pixels, 6 * self.size**2, 3)


@dataclass
class TransportRows:
    """Per-pixel rows [N, 6 R^2, 3] float64 (mean over spp) by category; those not asked for are None."""

    background: np.ndarray | None
    direct: np.ndarray | None
    indirect: np.ndarray | None

    def radiance(self, cube: np.ndarray, which: tuple[str, ...] = ("background", "direct", "indirect")):
        """Radiance [N, 3] float64 of every pixel under cube map [6, R, R, 3]: the rows dotted with it."""
        flat = np.asarray(cube, np.float64).reshape(-1, 3)
        return sum(np.einsum("njc,jc->nc", getattr(self, name), flat) for name in which)


def trace_rows(
    tracer: PathTracer,
    origins: np.ndarray,
    directions: np.ndarray,
    spp: int,
    size: int,
    rng: np.random.Generator,
    max_depth: int,
    categories: tuple[int, ...] = (INDIRECT,),
    stratified: bool = True,
) -> TransportRows:
    """Trace `spp` paths along each camera ray and bin their escapes into rows of a 6 x `size`^2 cube.
    `tracer` should light the scene with `lighting.uniform_cube` (any positive sampler is unbiased).
    `stratified`: a pixel's paths take strata of their first vertex's uniforms (`workers.render.stratified`),
    so that the bounces an indirect row integrates over cover the hemisphere evenly."""
    n = len(origins)
    out = {c: np.zeros((n, 6 * size**2, 3)) for c in categories}
    per_chunk = max(1, MAX_PATHS_PER_TRACE // spp)
    for start in range(0, n, per_chunk):
        stop = min(start + per_chunk, n)
        pixels = np.repeat(np.arange(stop - start), spp)
        binner = EscapeBinner(pixels, size)
        stream = StratifiedUniforms(rng, stop - start, spp) if stratified else rng
        tracer.trace(
            origins[start:stop][pixels], directions[start:stop][pixels], stream, max_depth, observer=binner
        )
        for c in categories:
            out[c][start:stop] = binner.rows(stop - start, c) / spp
    return TransportRows(out.get(BACKGROUND), out.get(DIRECT), out.get(INDIRECT))
