"""The neural shell in our path tracer: light transport through the shell as Eq. 6.3-6.4 (Sec. 6.2.8),
plugged in as the tracer's `Aggregate` (`workers.render.aggregate`), so no integrator code changes.

A ray meeting the shell is marched through its prisms (`shell.Shell.intervals`), with stratified samples
whose (u, v, height) come from the exact inverse prism map; the decoder gives extinction there, per slab
height, so a step's optical depth is measured in the slab's coordinates (`Shell.slab_length`): where a
prism widens over a convex surface, a sideways step crosses less of the generated slab than its world
length over h. The ray
then scatters at sample i with probability w_i = T_i (1 - exp(-sigma_i delta_i)) (the scattered term) or
passes with probability T (the uncollided term, carried on by the tracer to whatever lies behind): an
unbiased mixture whose weight is 1. Where a ray leaves a prism through its base (the skin), the base is
an opaque last sample, as in training. At a scattering point the tracer samples the light and one
direction; `throughput` is the learned rho(y, wo, wi) (radiance per unit irradiance from wi), the
albedo-weighted transport integrated over the slab's boundary, so a continuing ray starts where it
leaves the shell (`exit_distance`) and shadow rays test the shell stochastically by its transmittance.

A sample's cone footprint is clamped to the widest the training views contain
(`sampling.widest_footprint`): wider ones (a mesh seen from farther than the training cameras, in slab
heights) would read the decoder out of its training distribution, with a height encoding damped and mip
levels it never saw. Beyond it the pixel is filtered by the path tracer's jittered samples instead of the
mip stack. Trained on fine views only, the default preset's fur ball was seen at 3 to 4 times the widest
trained footprint and the clamp bound 68% of its samples (unclamped, FLIP rose with spp: 0.527 / 0.519 /
0.554 at 1 / 4 / 16 spp; clamped 0.467 / 0.322 / 0.288; 500 steps, seed 5). The default preset's coarse
views (footprints to about 1.0 slab heights, elevations 40-85 degrees) leave the ball's samples unclamped.

A scattering event is identified by its shell coordinates and its sample's footprint packed into the
protocol's int64 triple: (prism << 20 | height in 2^-20 steps, float32 bits of b1 and b2, float32 bits of
the height variance and footprint radius), so `throughput` reads rho from the hidden state of the very
sample the event was drawn from (the mip level and height encoding training rendered it with).

An interval ends on the skin where it leaves through the prism's base, or where the ray is cut by a
surface hit (`t_max`) within `FLOOR_LIFT` of the base: the base is the covered mesh itself, and the
float32 hit distance places it up to ~1e-5 shell heights off the prism's float64 base (a thin shell far
from the origin), so a tight tolerance there let rays through to the mesh's own material.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import widest_footprint
from workers.models.mesogan.shell import Intervals, Shell
from workers.models.mesogan.slab import Window
from workers.models.mesogan.volume import HEIGHT_TO_RADIANS, mip_level, sample_mipmapped
from workers.render.aggregate import AggregateEvents

HEIGHT_BITS = 20
OPAQUE = 60.0  # optical depth standing for the opaque base: exp(-60) ~ 1e-26, so alpha rounds to 1
MIN_RISE = 0.5  # grazing rays march at most twice the step of a ray along the normal
MAX_STEPS_PER_INTERVAL = 4  # times `samples`: long grazing intervals in one prism
FLOOR_LIFT = 1e-3  # a base event sits this fraction of the shell height above the skin (no self-hits)


@dataclass
class NeuralMaterial:
    """A generated plane over the UV square and what its decoder needs: the trained model, the plane's
    mip stack and window, and the appearance parameters."""

    model: MesoGAN
    config: MesoganConfig
    stack: list[torch.Tensor]
    window: Window
    appearance: torch.Tensor  # (3,) the strands' colour (`Appearance.color`)

    @property
    def widest_footprint(self) -> float:
        """The widest cone radius (slab heights) the decoder was trained at."""
        return widest_footprint(self.config)

    def hidden(self, uv: np.ndarray, height: np.ndarray, variance: np.ndarray, radius: np.ndarray):
        """Density (per slab height) and hidden state at mesh UVs, heights in [0, 1] and footprints."""
        device = self.stack[0].device
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(device)  # noqa: E731
        grid = f32(uv[:, ::-1])[None]  # the plane's x runs along u: grid_sample's (axis 1, axis 0) = (v, u)
        level = (
            mip_level(f32(radius)[None], self.window.texel, len(self.stack))
            if self.config.mipmapping
            else torch.zeros_like(grid[..., 0])
        )
        with torch.no_grad():
            features = sample_mipmapped(self.stack, grid, level)[0]
            return self.model.decoder.density(
                features, f32(height) * HEIGHT_TO_RADIANS, f32(variance) * HEIGHT_TO_RADIANS**2
            )

    def rho(self, hidden: torch.Tensor, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(hidden.device)  # noqa: E731
        with torch.no_grad():
            out = self.model.decoder.rho(
                hidden, self.appearance.expand(len(hidden), -1), f32(light), f32(view)
            )
        return out[:, :3].double().cpu().numpy()


def _pack_floats(high: np.ndarray, low: np.ndarray) -> np.ndarray:
    bits = lambda a: np.ascontiguousarray(a, np.float32).view(np.uint32).astype(np.int64)  # noqa: E731
    return (bits(high) << 32) | bits(low)


def _unpack_floats(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    floats = lambda a: a.astype(np.uint32).view(np.float32).astype(np.float64)  # noqa: E731
    return floats((packed >> 32) & 0xFFFFFFFF), floats(packed & 0xFFFFFFFF)


def pack_events(
    prism: np.ndarray, b: np.ndarray, height: np.ndarray, variance: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    q = np.clip(np.round(height * (1 << HEIGHT_BITS)), 0, (1 << HEIGHT_BITS) - 1).astype(np.int64)
    return np.stack(
        [
            (prism.astype(np.int64) << HEIGHT_BITS) | q,
            _pack_floats(b[:, 1], b[:, 2]),
            _pack_floats(variance, radius),
        ],
        1,
    )


def unpack_events(voxel: np.ndarray) -> tuple[np.ndarray, ...]:
    """Prism, barycentrics (N, 3), height, height variance and footprint radius of packed events."""
    prism = voxel[:, 0] >> HEIGHT_BITS
    height = (voxel[:, 0] & ((1 << HEIGHT_BITS) - 1)) / float(1 << HEIGHT_BITS)
    b1, b2 = _unpack_floats(voxel[:, 1])
    variance, radius = _unpack_floats(voxel[:, 2])
    return prism, np.stack([1 - b1 - b2, b1, b2], 1), height, variance, radius


def _running_max_by_ray(ray: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Running maximum of finite `values` restarting at every new ray (rows grouped by ray): each ray's
    rows are lifted above all earlier rays' by a ray-wise offset."""
    offset = np.cumsum(np.r_[0, ray[1:] != ray[:-1]]) * (2 * np.abs(values).max() + 1.0)
    return np.maximum.accumulate(values + offset) - offset


def ray_uniforms(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """A uniform in [0, 1) per ray from a hash of its bits: shadow tests are random yet reproducible
    whatever thread or batch asks (the protocol gives `occluded` no random stream)."""
    bits = np.ascontiguousarray(np.concatenate([origins, directions], 1)).view(np.uint64)
    h = np.full(len(origins), 0x9E3779B97F4A7C15, np.uint64)
    with np.errstate(over="ignore"):
        for k in range(bits.shape[1]):
            h ^= bits[:, k] + np.uint64(0x9E3779B97F4A7C15) + (h << np.uint64(6)) + (h >> np.uint64(2))
            h ^= h >> np.uint64(31)
            h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(29)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


@dataclass
class _Samples:
    """Samples along interval rows: the interval, distance, shell coordinates, footprint and optical
    depth."""

    interval: np.ndarray
    t: np.ndarray
    prism: np.ndarray
    b: np.ndarray
    height: np.ndarray
    variance: np.ndarray
    radius: np.ndarray
    optical: np.ndarray


class ShellAggregate:
    """The neural material on a shell, as the path tracer's `Aggregate` (module docstring).

    `cone` is the pixel footprint's radius per unit distance (camera rays; secondary rays reuse it from
    their own origin, so they read finer levels than a ray differential would)."""

    def __init__(self, shell: Shell, material: NeuralMaterial, samples: int, cone: float = 0.0) -> None:
        self.shell, self.material, self.samples, self.cone = shell, material, samples, cone
        self.widest = material.widest_footprint
        self.density_queries = 0

    # ------------------------------------------------------------------ marching

    def _footprint(self, t, axis, d, prism, b) -> tuple[np.ndarray, np.ndarray]:
        """Height variance and footprint radius (slab heights) of cone segments at distances `t` with
        variance `axis` along the ray (`slab.march`, `volume.footprint_radius`), the cone no wider than
        training's (module docstring)."""
        radial = np.minimum(t * self.cone / self.shell.height, self.widest) ** 2
        z2 = np.einsum("ij,ij->i", d, self.shell.normal(prism, b)) ** 2
        variance = axis * z2 + radial * (1 - z2)
        return variance, np.sqrt(np.minimum(radial, radial * z2 + axis * (1 - z2)))

    def _march(self, origins, directions, t_max, iv: Intervals, rng) -> _Samples:
        """Stratified samples (random offsets from `rng`, midpoints without) at the step training marched
        with, `samples` per crossing of the slab's height (slab.march), at least one per interval and
        at most `MAX_STEPS_PER_INTERVAL` `samples`, and an opaque sample where an interval ends on the
        skin (module docstring). A ray crossing several prisms is not sampled `samples` times in each."""
        shell, s = self.shell, self.samples
        length = iv.leave - iv.enter
        rise = np.abs(np.einsum("ij,ij->i", directions[iv.ray], self.shell.normals[iv.prism].mean(1)))
        chord_step = shell.height / (np.clip(rise, MIN_RISE, 1.0) * s)
        count = np.clip(np.ceil(length / chord_step - 1e-9), 1, MAX_STEPS_PER_INTERVAL * s).astype(np.int64)
        step = length / count
        leave_point = origins[iv.ray] + iv.leave[:, None] * directions[iv.ray]
        b_leave, h_leave = shell.inverse(iv.prism, leave_point)
        slab_step = shell.slab_length(iv.prism, origins[iv.ray] + iv.enter[:, None] * directions[iv.ray],
                                      b_leave, h_leave) / count  # fmt: skip
        rows = np.repeat(np.arange(len(iv.ray)), count)
        k = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
        u = rng.random(len(rows)) if rng is not None else np.full(len(rows), 0.5)
        t = iv.enter[rows] + (k + u) * step[rows]
        o, d = origins[iv.ray[rows]], directions[iv.ray[rows]]
        b, height = shell.inverse(iv.prism[rows], o + t[:, None] * d)
        height = np.clip(height, 0.0, 1.0)
        variance, radius = self._footprint(t, slab_step[rows] ** 2 / 12, d, iv.prism[rows], b)
        self.density_queries += len(t)
        density, _ = self.material.hidden(shell.uv(iv.prism[rows], b), height, variance, radius)
        optical = np.minimum(density.double().cpu().numpy() * slab_step[rows], OPAQUE)
        cut = iv.leave >= t_max[iv.ray]
        floor = np.flatnonzero((h_leave < 1e-6) | (cut & (h_leave < FLOOR_LIFT)))
        if len(floor):
            # The skin: an opaque sample a little above it (no self-hits), read at height 0 as in training.
            d_floor = directions[iv.ray[floor]]
            cos = np.abs(np.einsum("ij,ij->i", d_floor, shell.normal(iv.prism[floor], b_leave[floor])))
            back = FLOOR_LIFT * shell.height / np.maximum(cos, 1e-3)
            t_floor = np.maximum(iv.leave[floor] - back, iv.enter[floor])
            v_floor, r_floor = self._footprint(
                t_floor, np.zeros(len(floor)), d_floor, iv.prism[floor], b_leave[floor]
            )
            rows = np.concatenate([rows, floor])
            t = np.concatenate([t, t_floor])
            b = np.concatenate([b, b_leave[floor]])
            height = np.concatenate([height, np.zeros(len(floor))])
            variance = np.concatenate([variance, v_floor])
            radius = np.concatenate([radius, r_floor])
            optical = np.concatenate([optical, np.full(len(floor), OPAQUE)])
        order = np.lexsort((t, iv.ray[rows]))
        return _Samples(
            rows[order],
            t[order],
            iv.prism[rows[order]],
            b[order],
            height[order],
            variance[order],
            radius[order],
            optical[order],
        )

    @staticmethod
    def _transmittance_before(ray: np.ndarray, optical: np.ndarray) -> np.ndarray:
        """exp(-optical depth of the same ray's earlier samples), samples grouped by ray in order."""
        total = np.cumsum(optical)
        starts = np.r_[0, np.flatnonzero(np.diff(ray)) + 1]
        offset = np.repeat(total[starts] - optical[starts], np.diff(np.r_[starts, len(ray)]))
        return np.exp(-(total - optical - offset))

    # ------------------------------------------------------------------ the Aggregate protocol

    def first_events(self, origins, directions, t_min, t_max, rng) -> AggregateEvents:
        n = len(origins)
        events = AggregateEvents(
            np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3), np.int64), np.ones(n)
        )
        iv = self.shell.intervals(origins, directions, t_min, t_max)
        if len(iv.ray) == 0:
            return events
        samples = self._march(origins, directions, t_max, iv, rng)
        ray = iv.ray[samples.interval]
        weight = self._transmittance_before(ray, samples.optical) * -np.expm1(-samples.optical)
        u = rng.random(n)
        cumulative = np.cumsum(weight)
        starts = np.r_[0, np.flatnonzero(np.diff(ray)) + 1]
        before = np.repeat(cumulative[starts] - weight[starts], np.diff(np.r_[starts, len(ray)]))
        chosen = np.flatnonzero(cumulative - before > u[ray])
        rays, first = np.unique(ray[chosen], return_index=True)
        pick = chosen[first]
        events.found[rays] = True
        events.t[rays] = samples.t[pick]
        events.voxel[rays] = pack_events(
            samples.prism[pick],
            samples.b[pick],
            samples.height[pick],
            samples.variance[pick],
            samples.radius[pick],
        )
        return events

    def occluded(self, origins, directions, t_min, t_max) -> np.ndarray:
        n = len(origins)
        iv = self.shell.intervals(origins, directions, t_min, t_max)
        blocked = np.zeros(n, bool)
        if len(iv.ray) == 0:
            return blocked
        samples = self._march(origins, directions, t_max, iv, None)
        depth = np.zeros(n)
        np.add.at(depth, iv.ray[samples.interval], samples.optical)
        return ray_uniforms(origins, directions) < -np.expm1(-depth)

    def throughput(self, voxel, wo, wi) -> np.ndarray:
        prism, b, height, variance, radius = unpack_events(voxel)
        tangent, bitangent, normal = self.shell.frame(prism, b)
        local = lambda w: np.stack([(w * tangent).sum(1), (w * bitangent).sum(1), (w * normal).sum(1)], 1)  # noqa: E731
        _, hidden = self.material.hidden(self.shell.uv(prism, b), height, variance, radius)
        return self.material.rho(hidden, local(wi), local(wo))

    def exit_distance(self, voxel, origins, directions) -> np.ndarray:
        n = len(origins)
        iv = self.shell.intervals(origins, directions, np.zeros(n), np.full(n, np.inf))
        out = np.zeros(n)
        if len(iv.ray) == 0:
            return out
        # Each ray's run of touching intervals (prism to prism) that starts at its origin, and its end.
        gap = 1e-6 * max(self.shell.height, 1e-12)
        first = np.r_[True, iv.ray[1:] != iv.ray[:-1]]
        previous_end = np.r_[-np.inf, _running_max_by_ray(iv.ray, iv.leave)[:-1]]
        breaks = first | (iv.enter > previous_end + gap)
        run = np.cumsum(breaks) - 1
        ends = np.full(run[-1] + 1, -np.inf)
        np.maximum.at(ends, run, iv.leave)
        rows = np.flatnonzero(first & (iv.enter <= gap))
        out[iv.ray[rows]] = ends[run[rows]]
        return out
