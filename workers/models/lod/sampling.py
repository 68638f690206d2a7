"""Training data generated on the fly (Weier et al. 2023, Sec. 5).

A sample picks an occupied LoD-0 voxel and a LoD uniformly and takes the voxel's ancestor at that LoD, so
coarse voxels get samples in proportion to the fine voxels they hold. In it: w_o uniform on the sphere, a
face by projected area (|n . w_o|), p_o uniform on that face and p_i where the ray from p_o along -w_o
leaves the voxel: segment densities are then uniform inside the voxel (Fig. 12). The box is grown by
`domain_extrusion` of the voxel size so geometry lying on a voxel face is learned robustly (Fig. 13).

Every pair is a visibility sample (Embree over the asset's triangles). Occluded pairs, whose segment meets
the asset inside the voxel, are appearance samples: a path traced from p_o along -w_o and confined to the
voxel, with a shadow ray towards w_i (uniform) to the voxel's boundary at every vertex, BSDF importance
sampling and albedo-based Russian roulette, estimates phi_V(w_o, w_i) of Eq. 3 without bias (Sec. 5.2).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from workers.models.lod.config import LodConfig
from workers.models.lod.grid import LodGrid
from workers.models.lod.segments import (
    add_unblocked_throughput,
    boundary_pair_rows,
    box_exit_rows,
    cube_coordinates_f32,
    rays_leaving_voxels,
    roulette_survivors,
    take_pair_rows,
    take_voxel_paths,
    uniform_sphere_rows,
    voxel_ancestors,
    voxel_centres_f32,
    voxel_shadow_rays,
)
from workers.render import wavefront
from workers.render.bsdf import eval_bsdf, sample_bsdf
from workers.render.embree import SubsetRayScene
from workers.render.integrator import PathTracer
from workers.render.intersector import Hits
from workers.runtime.sources import Batch, batch_rng
from workers.scene.geometry.compile import CompiledScene
from workers.scene.portability.reference import SceneRef

RR_MAX_SURVIVAL = 0.95


def asset_triangles(scene: CompiledScene, names: list[str]) -> np.ndarray:
    """Indices of the triangles of the objects `names` (every instance) in the compiled scene."""
    ids = [np.arange(lo, hi) for obj in scene.objects if obj.name in names for lo, hi in obj.triangle_ranges]
    return np.concatenate(ids) if ids else np.zeros(0, np.int64)


def asset_tracer(scene: CompiledScene, names: list[str]) -> PathTracer:
    """A path tracer that sees only the asset's triangles (materials and lights of the whole scene)."""
    return PathTracer(scene, intersector=SubsetRayScene(scene.positions, asset_triangles(scene, names)))


def box_exit(lo: np.ndarray, hi: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance at which rays starting inside (or on) boxes (N, 3) leave them (>= 0)."""
    shape = np.shape(origins)
    return box_exit_rows(
        *(np.ascontiguousarray(np.broadcast_to(a, shape), np.float64) for a in (lo, hi, origins, directions))
    )


@dataclass
class BoundaryPairs:
    """Segments through voxels: entry p_o, exit p_i along -w_o, and the (grown) voxel boxes."""

    p_o: np.ndarray
    p_i: np.ndarray
    wo: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    length: np.ndarray  # |p_i - p_o|

    def take(self, rows: np.ndarray) -> BoundaryPairs:
        return BoundaryPairs(
            *take_pair_rows(np.asarray(rows, np.int64), *(getattr(self, f.name) for f in fields(self)))
        )


def boundary_pairs(
    grid: LodGrid,
    level: np.ndarray,
    cells: np.ndarray,
    rng: np.random.Generator,
    grow: float,
    wo: np.ndarray | None = None,
) -> BoundaryPairs:
    """One segment per voxel (level, cell) with the density of Sec. 5.1 (module docstring); `wo` fixes
    the directions instead of drawing them."""
    n = len(cells)
    if wo is None:
        wo = uniform_sphere_rows(rng.random((n, 2)))
    u_face, u_point = rng.random(n), rng.random((n, 3))
    box = np.asarray(grid.lo, np.float64), float(grid.extent), np.asarray(grid.resolutions, np.float64)
    voxels = np.asarray(level, np.int64), np.asarray(cells, np.int64), float(grow)
    lo, hi, p_o, p_i, length = boundary_pair_rows(
        *box, *voxels, np.ascontiguousarray(wo, np.float64), u_face, u_point
    )
    return BoundaryPairs(p_o, p_i, wo, lo, hi, length)


def sample_voxels(grid: LodGrid, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(level, cell) of n voxels: an occupied LoD-0 voxel and a LoD uniformly, then its ancestor."""
    fine = grid.keys[0][rng.integers(len(grid.keys[0]), size=n)]
    level = rng.integers(grid.levels, size=n)
    return level, voxel_ancestors(fine, grid.resolutions[0], grid.shifts, level)


def first_asset_hits(tracer: PathTracer, pairs: BoundaryPairs) -> tuple[np.ndarray, Hits]:
    """Whether each segment meets the asset (the visibility label's complement), and the hits (those past
    the segment may be misses). `tracer` comes from `asset_tracer`: its Embree scene stops at the segment's
    end (with the bounce rays' bound below, a dense_foliage batch's Embree time 20 -> 11 CPU ms: its rays
    would go on through the foliage)."""
    hits = tracer.rays.intersect(pairs.p_o, -pairs.wo, t_max=pairs.length)
    return hits.found & (hits.t < pairs.length), hits


def throughput_estimates(
    tracer: PathTracer,
    pairs: BoundaryPairs,
    hits: Hits,
    wi: np.ndarray,
    rng: np.random.Generator,
    max_bounces: int,
) -> np.ndarray:
    """(N, 3) one-sample estimates of phi_V(w_o, w_i) for segments that met the asset at `hits` (the
    `asset_tracer`'s Embree hits: no predicted surfaces to carry along the bounces)."""
    n = len(wi)
    value = np.zeros((n, 3))
    live = np.arange(n)
    o, d, beta, lo, hi = pairs.p_o, -pairs.wo, np.ones((n, 3)), pairs.lo, pairs.hi  # beta: float64, owned
    for _ in range(max_bounces):
        if len(live) == 0:
            break
        sh = tracer.shade(hits, o, d)
        light = wi[live]
        rows = np.arange(len(live))
        f_cos, _ = eval_bsdf(sh.surf, sh.wo_local, wavefront.to_local_rows(rows, light, sh.fs, sh.ft, sh.ns))
        f_cos = _f64(f_cos)
        lit, origin, t_max = voxel_shadow_rays(f_cos, light, sh.position, sh.ng, sh.scale, lo, hi)
        if len(lit):
            blocked = tracer.rays.occluded(origin, light[lit], t_max)
            add_unblocked_throughput(value, live, lit, beta, f_cos, blocked)
        u = rng.random((len(live), 4))
        sampled, weight, _, _, eta = sample_bsdf(sh.surf, sh.wo_local, u[:, :2], u[:, 2])
        survivors = roulette_survivors(beta, _f64(weight), _f64(eta), u[:, 3], RR_MAX_SURVIVAL)
        o, d, t_exit = rays_leaving_voxels(
            survivors, _f64(sampled), sh.fs, sh.ft, sh.ns, sh.position, sh.ng, sh.scale, lo, hi
        )
        hits = tracer.rays.intersect(o, d, t_max=t_exit)
        live, o, d, beta, lo, hi, *hit = take_voxel_paths(
            survivors, t_exit, live, beta, lo, hi, o, d, hits.prim, hits.t, hits.u, hits.v
        )
        hits = Hits(*hit)
    return np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0)


@dataclass(frozen=True)
class LodSourceConfig:
    """What a sampler process needs to rebuild the source: the scene, the asset and its LoD-0 voxels."""

    scene: SceneRef
    objects: list[str]
    lod: LodConfig
    grid: dict[str, np.ndarray]  # LodGrid.arrays()


class LodSource:
    """Batches of visibility pairs and appearance estimates (a `SampleSource`)."""

    def __init__(self, config: LodSourceConfig, seed: int) -> None:
        self.config, self.seed = config, seed
        self.tracer = asset_tracer(config.scene.compiled(), config.objects)
        self.grid = LodGrid.from_arrays(config.grid)

    def batch(self, index: int) -> Batch:
        rng = batch_rng(self.seed, index)
        lod = self.config.lod
        level, cells = sample_voxels(self.grid, lod.batch_size, rng)
        pairs = boundary_pairs(self.grid, level, cells, rng, lod.domain_extrusion)
        occluded, hits = first_asset_hits(self.tracer, pairs)
        rows = np.flatnonzero(occluded)
        wi = uniform_sphere_rows(rng.random((len(rows), 2)))
        appearance = pairs.take(rows)
        value = throughput_estimates(self.tracer, appearance, hits.take(rows), wi, rng, lod.max_voxel_bounces)
        grid = self.grid
        resolutions = np.asarray(grid.resolutions, np.int64)
        return {
            "vis_p_o": torch.from_numpy(cube_coordinates_f32(pairs.p_o, grid.lo, float(grid.extent))),
            "vis_p_i": torch.from_numpy(cube_coordinates_f32(pairs.p_i, grid.lo, float(grid.extent))),
            "vis_label": _tensor(~occluded),
            "app_centre": torch.from_numpy(voxel_centres_f32(rows, level, cells, resolutions)),
            "app_wo": _tensor(appearance.wo),
            "app_wi": _tensor(wi),
            "app_value": _tensor(value),
        }


def _f64(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array, np.float64)


def _tensor(array: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array, np.float32))
