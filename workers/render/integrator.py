"""Wavefront unidirectional path tracing: every bounce is a handful of compiled passes over all live
paths (`workers.render.wavefront`), with Embree answering closest-hit and shadow queries in bulk.

Next-event estimation and BSDF sampling are combined with the power heuristic; Russian roulette
starts at `rr_depth`, by Mitsuba's rule (throughput times the path's eta^2; `wavefront._roulette`).
`max_depth` counts path segments as Mitsuba does: 1 shows emitters only, 2 is direct lighting. This is
the API the training samplers call: `trace` for radiance along given rays, `first_hits` for surface
records, `occluded` for visibility.

Extension points, none of which names a model kind: geometry answers through `Intersector`s
(`workers.render.intersector`; hits may carry predicted surfaces), materials are BSDF families
registered by name (`workers.render.bsdf`), an `Aggregate` scatters light in voxels beside the surfaces
(`workers.render.aggregate`; scene materials drawn as one are families registered by name too,
`workers.render.aggregate_materials`), and a `PathObserver` sees the events of traced paths
(`workers.render.observer`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from workers.render import heap, wavefront
from workers.render.aggregate import Aggregate, AggregateEvents
from workers.render.aggregate_materials import scene_aggregate, used_aggregate_materials
from workers.render.bsdf import SurfaceBatch, eval_bsdf, sample_bsdf
from workers.render.embree import RayScene
from workers.render.environment import NO_MAP, EnvironmentMapLight
from workers.render.intersector import Hits, Intersector
from workers.render.lights import LightSample, LightSampler
from workers.render.materials import MaterialTable
from workers.render.observer import PathObserver
from workers.render.sampling import (
    dot,
    max3,
    power_heuristic,
    square_to_uniform_sphere,
    to_local,
    to_world,
)
from workers.render.stratified import surface_uniforms
from workers.render.wavefront import RAY_OFFSET
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Camera
from workers.scene.geometry.compile import CompiledScene

UNIFORM_SPHERE_PDF = 1.0 / (4.0 * np.pi)
_NO_ROWS, _NO_ROWS3 = np.zeros(0), np.zeros((0, 3))  # per-row environment values the lat-long kernels skip


@dataclass
class TraceResult:
    radiance: np.ndarray  # (N, 3) float64, finite, >= 0
    bounces: np.ndarray  # (N,) int: segments traced before the path ended
    rays_traced: int  # closest-hit plus shadow rays, for throughput figures


@dataclass
class SurfaceRecords:
    """First hits of a batch of rays; arrays are full-length, meaningful where `hit`."""

    hit: np.ndarray  # (N,) bool
    t: np.ndarray  # (N,) distance (inf on a miss)
    position: np.ndarray  # (N, 3)
    geometric_normal: np.ndarray  # (N, 3), follows the triangle's winding
    shading_normal: np.ndarray  # (N, 3)
    uv: np.ndarray  # (N, 2)
    prim: np.ndarray  # (N,) triangle index, -1 on a miss
    material_id: np.ndarray  # (N,)
    object_id: np.ndarray  # (N,)
    instance_id: np.ndarray  # (N,)
    albedo: np.ndarray  # (N, 3)
    roughness: np.ndarray  # (N,)
    emission: np.ndarray  # (N, 3) radiance emitted towards the ray origin


@dataclass
class _Paths:
    """The live paths of a wavefront: pixel index, current ray, throughput and the last scattering's pdf.

    `eta2` is the product of the squared relative IORs of the path's transmissions (float64, as beta),
    for Russian roulette (`wavefront._roulette`); `t_min` is where the aggregate walk starts along the ray
    (past the voxel the ray left, else 0);
    `spread` is a camera ray's cone angle (radians; 0 once scattered), for mipmapped texture lookups."""

    idx: np.ndarray
    o: np.ndarray
    d: np.ndarray
    beta: np.ndarray
    eta2: np.ndarray
    prev_pdf: np.ndarray
    prev_delta: np.ndarray
    t_min: np.ndarray
    spread: np.ndarray

    def take(self, rows: np.ndarray) -> _Paths:
        arrays = (
            np.asarray(self.idx, np.int64),
            *map(_f64, (self.o, self.d, self.beta, self.eta2, self.prev_pdf)),
        )
        arrays += (np.asarray(self.prev_delta, np.bool_), _f64(self.t_min), _f64(self.spread))
        return _Paths(*wavefront.take_paths(np.asarray(rows, dtype=np.int64), arrays))

    @staticmethod
    def concatenate(a: _Paths, b: _Paths) -> _Paths:
        return _Paths(*(np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(a)))


@dataclass
class _Scattered:
    paths: _Paths
    rays_traced: int


@dataclass
class Shading:
    """Surface points ready for BSDF queries: materials, and a frame whose normal faces the viewer (except
    on refractive surfaces); `wo_local` is the direction back along the arriving ray in that frame."""

    position: np.ndarray
    ng: np.ndarray
    scale: np.ndarray  # coordinate magnitude for `PathTracer.offset`
    surf: SurfaceBatch
    fs: np.ndarray
    ft: np.ndarray
    ns: np.ndarray
    wo_local: np.ndarray

    def to_world(self, v: np.ndarray) -> np.ndarray:
        return to_world(v, self.fs, self.ft, self.ns)

    def to_local(self, v: np.ndarray) -> np.ndarray:
        return to_local(v, self.fs, self.ft, self.ns)


@dataclass
class _Interaction:
    position: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    uv: np.ndarray
    scale: np.ndarray  # coordinate magnitude that float32 rounding errors are relative to
    material: np.ndarray  # scene material ids


class PathTracer:
    """Everything needed to trace paths in one compiled scene; safe to share between threads."""

    def __init__(
        self,
        scene: CompiledScene,
        robust: bool = True,
        intersector: Intersector | None = None,
        primary: Intersector | None = None,
        aggregate: Aggregate | None = None,
        aggregate_next_event: bool = True,
        view: Camera | None = None,
    ):
        """`intersector` answers closest-hit and occlusion queries in place of an Embree scene over every
        triangle (e.g. a model's objects beside Embree); it must index hits by the scene's triangles.
        `primary` (default: the same) answers the first segment of paths and `first_hits`, as a
        rasteriser would for camera rays. `aggregate` scatters light in voxels beside the surfaces
        (`workers.render.aggregate`); by default the one the scene's aggregate materials make
        (`workers.render.aggregate_materials`), for paths starting at the camera `view` (default: the
        scene's). `aggregate_next_event` samples lights from its scattering voxels."""
        heap.keep_freed_arrays()
        self.scene = scene
        if aggregate is None:
            aggregate = scene_aggregate(scene, view or scene.spec.camera)
        elif used := used_aggregate_materials(scene):
            name = next(iter(next(iter(used.values()))))
            raise SceneError(f"materials.{name}", "this renderer brings its own aggregate; it cannot draw it")
        self.aggregate = aggregate
        self.aggregate_next_event = aggregate_next_event
        self.rays = intersector if intersector is not None else RayScene(scene.positions, robust=robust)
        self.primary = primary if primary is not None else self.rays
        self.materials = MaterialTable(scene)
        self.lights = LightSampler(
            scene, self.materials.emission_scale if self.materials.emission_textured else None
        )
        positions = scene.positions.astype(np.float64)
        ng = np.ascontiguousarray(scene.geometric_normals, dtype=np.float64)
        self._ns = np.ascontiguousarray(scene.shading_normals, dtype=np.float64)
        self._uv = np.ascontiguousarray(scene.uvs, dtype=np.float64)
        self._emission = np.ascontiguousarray(scene.emission, dtype=np.float64)
        # Triangles whose shading normals differ from the geometric one need interpolation.
        smooth = np.abs(self._ns - ng[:, None, :]).max(axis=(1, 2)) > 1e-6
        self._triangles = wavefront.triangle_records(
            ng, np.abs(positions).max(axis=(1, 2)), smooth, scene.material_ids, self._emission,
            scene.two_sided_emission,
        )  # fmt: skip
        self._needs_uv = self.materials.needs_uv
        with np.errstate(divide="ignore"):
            uv_edges = self._uv[:, 1:] - self._uv[:, :1]
            uv_area = 0.5 * np.abs(
                uv_edges[:, 0, 0] * uv_edges[:, 1, 1] - uv_edges[:, 0, 1] * uv_edges[:, 1, 0]
            )
            self._log2_uv_per_length = 0.5 * np.log2(uv_area / np.maximum(scene.areas, 1e-300))
        self._has_emitters = bool((scene.emission > 0).any())

    # ------------------------------------------------------------------ geometry helpers

    def _interaction(
        self, hits: Hits, origins: np.ndarray, directions: np.ndarray, need_uv: bool
    ) -> _Interaction:
        """Surface data at hits (`wavefront.surface_points`): the position is o + t d (float32 t: error far
        below the ray offset); predicted surfaces (`Hits.surface`) replace both normals and the material."""
        position, ng, ns, uv, scale, material = wavefront.surface_points(
            _f64(origins),
            _f64(directions),
            _f64(hits.t),
            np.asarray(hits.prim, dtype=np.int64),
            _f64(hits.u),
            _f64(hits.v),
            self._triangles,
            self._ns,
            self._uv,
            need_uv,
        )
        if hits.surface is not None and hits.surface.where.any():
            predicted = np.flatnonzero(hits.surface.where)
            ng[predicted] = hits.surface.normal[predicted]
            ns[predicted] = hits.surface.normal[predicted]
            material[predicted] = hits.surface.material[predicted]
        return _Interaction(position, ng, ns, uv, scale, material)

    @staticmethod
    def offset(position: np.ndarray, ng: np.ndarray, direction: np.ndarray, scale: np.ndarray | None = None):
        """Move a ray origin off the surface, to the side `direction` leaves by (no self-hits).

        The distance is relative to `scale` (by default the point's own coordinates): Embree works
        in float32, so its errors grow with the magnitude of the triangle's vertices.
        """
        if scale is None:
            scale = np.abs(position).max(axis=1)
        return wavefront.offset_origins(_f64(position), _f64(ng), _f64(direction), _f64(scale))

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        return self._occluded(origins, directions, t_max)

    # ------------------------------------------------------------------ first hits

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> SurfaceRecords:
        n = len(origins)
        hits = self.primary.intersect(origins, directions)
        found = hits.found
        rec = SurfaceRecords(
            hit=found,
            t=np.full(n, np.inf),
            position=np.zeros((n, 3)),
            geometric_normal=np.zeros((n, 3)),
            shading_normal=np.zeros((n, 3)),
            uv=np.zeros((n, 2)),
            prim=np.full(n, -1, np.int64),
            material_id=np.full(n, -1, np.int64),
            object_id=np.full(n, -1, np.int64),
            instance_id=np.full(n, -1, np.int64),
            albedo=np.zeros((n, 3)),
            roughness=np.zeros(n),
            emission=np.zeros((n, 3)),
        )
        sel = np.flatnonzero(found)
        if len(sel) == 0:
            return rec
        sub = hits.take(sel)
        it = self._interaction(sub, origins[sel], directions[sel], need_uv=True)
        prim = sub.prim
        mat = it.material
        rec.t[sel], rec.position[sel], rec.uv[sel] = sub.t, it.position, it.uv
        rec.geometric_normal[sel], rec.shading_normal[sel], rec.prim[sel] = it.ng, it.ns, prim
        rec.material_id[sel] = mat
        rec.object_id[sel] = self.scene.object_ids[prim]
        rec.instance_id[sel] = self.scene.instance_ids[prim]
        rec.albedo[sel] = self._surfaces(sub, mat, it.uv).base
        rec.roughness[sel] = self.materials.roughness(mat)
        rec.emission[sel] = self._emitted(prim, directions[sel], it.ng, it.uv)
        return rec

    def _footprint(
        self, hits: Hits, it: _Interaction, d: np.ndarray, spread: np.ndarray
    ) -> np.ndarray | None:
        """log2 of the width in UV units of ray cones of angle `spread` at the hits (-inf where 0), as ray
        cones estimate texture LOD (Akenine-Moeller et al. 2019, eq. 34): cone width t * spread over
        |cos|, times the triangle's UV length per world length; None when no path has a cone."""
        if not self._needs_uv or not spread.any():
            return None
        width = spread * hits.t / np.maximum(np.abs(dot(d, it.ng)), 1e-6)
        with np.errstate(divide="ignore"):
            return self._log2_uv_per_length[hits.prim] + np.log2(width)

    def _tangents(self, hits: Hits) -> np.ndarray:
        """(N, 4) tangents (xyz, bitangent sign) interpolated at the hits, for normal maps."""
        return hits.interpolate(self.scene.tangents[hits.prim])

    def _surfaces(self, hits: Hits, mat: np.ndarray, uv: np.ndarray, footprint: np.ndarray | None = None):
        surf = self.materials.surfaces(mat, uv, footprint)
        if self.scene.vertex_colors is not None:
            surf.base *= hits.interpolate(self.scene.vertex_colors[hits.prim])
        if hits.surface is not None and hits.surface.where.any():
            surf.base[hits.surface.where] = hits.surface.albedo[hits.surface.where]
        return surf

    def _emitted(self, prim: np.ndarray, d: np.ndarray, ng: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Radiance the hit triangles `prim` emit back along the rays `d`."""
        prim = np.asarray(prim, dtype=np.int64)
        emitted = wavefront.emitted_radiance(prim, _f64(d), _f64(ng), self._triangles, self._emission)
        if self.materials.emission_textured:
            emitted = emitted * self.materials.emission_scale(self.scene.material_ids[prim], uv)
        return emitted

    # ------------------------------------------------------------------ path tracing

    def trace(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        rng: np.random.Generator,
        max_depth: int = 8,
        rr_depth: int = 5,
        observer: PathObserver | None = None,
        spread: float | np.ndarray = 0.0,
    ) -> TraceResult:
        """Radiance arriving at each origin from its direction (unit directions); `observer` sees the
        paths' events (`workers.render.observer`) and changes nothing traced. `spread` is the rays' cone
        angle (a camera's pixel angle), which selects textures' mip levels at the first hits."""
        n = len(origins)
        radiance = np.zeros((n, 3))
        bounces = np.zeros(n, np.int64)
        rays_traced = 0
        paths = _Paths(
            idx=np.arange(n),
            o=_f64(origins),
            d=_f64(directions),
            beta=np.ones((n, 3)),
            eta2=np.ones(n),
            prev_pdf=np.zeros(n),
            prev_delta=np.ones(n, bool),  # the camera ray: emitters it sees count fully
            t_min=np.zeros(n),
            spread=np.broadcast_to(np.asarray(spread, dtype=np.float64), (n,)).copy(),
        )
        env = self.lights.environment
        for segment in range(1, max_depth + 1):
            if len(paths.idx) == 0:
                break
            hits = (self.primary if segment == 1 else self.rays).intersect(paths.o, paths.d)
            rays_traced += len(paths.idx)
            bounces[paths.idx] = segment
            found = hits.found
            events = None
            if self.aggregate is not None:
                t_surface = np.where(found, hits.t, np.inf)
                events = self.aggregate.first_events(paths.o, paths.d, paths.t_min, t_surface, rng)
                paths.beta = paths.beta * events.weight[:, None]
                found = found & ~events.found

            miss = np.flatnonzero(~found if events is None else ~found & ~events.found)
            if len(miss) and (env is not None or observer is not None):
                self._escape(paths, miss, radiance, observer)

            roulette = segment >= rr_depth
            scattered = None
            if events is not None:
                at = np.flatnonzero(events.found)
                scattered = self._scatter_in_aggregate(
                    paths.take(at), events.take(at), segment, max_depth, roulette, rng, radiance, observer
                )
                rays_traced += scattered.rays_traced
            if len(miss) or events is not None:
                keep = np.flatnonzero(found)
                paths = paths.take(keep)
                hits = hits.take(keep)
            paths, shadow_rays = self._scatter_at_surfaces(
                paths, hits, segment, max_depth, roulette, rng, radiance, observer
            )
            rays_traced += shadow_rays
            if scattered is not None:
                paths = _Paths.concatenate(paths, scattered.paths)
        np.nan_to_num(radiance, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return TraceResult(radiance, bounces, rays_traced)

    def _escape(self, paths: _Paths, miss: np.ndarray, radiance: np.ndarray, observer) -> None:
        """The environment's radiance seen by the escaped paths `miss` (MIS-weighted), and the observer's
        escape events."""
        env = self.lights.environment
        env_map = env.tables if isinstance(env, EnvironmentMapLight) else NO_MAP
        if env_map is NO_MAP:
            le, env_pdf = self.lights.environment_lookup(paths.d[miss])
        else:
            le, env_pdf = _NO_ROWS3, _NO_ROWS
        weight = wavefront.add_escapes(
            radiance if env is not None else np.zeros_like(radiance), miss, paths.idx, paths.beta, paths.d,
            paths.prev_pdf, paths.prev_delta, env_map, self.lights.env_prob, _f64(le), _f64(env_pdf),
        )  # fmt: skip
        if observer is not None:
            observer.on_escape(paths.idx[miss], paths.d[miss], paths.beta[miss] * weight[:, None])

    def _scatter_at_surfaces(
        self,
        paths: _Paths,
        hits: Hits,
        segment: int,
        max_depth: int,
        roulette: bool,
        rng,
        radiance: np.ndarray,
        observer: PathObserver | None,
    ) -> tuple[_Paths, int]:
        """Emission, next-event estimation and BSDF sampling at surface hits: the continuing paths (after
        Russian roulette where `roulette`)."""
        if len(paths.idx) == 0:
            return paths, 0
        idx, d, beta = paths.idx, paths.d, paths.beta
        it = self._interaction(hits, paths.o, d, self._needs_uv)
        if observer is not None:
            observer.on_surface(idx, it.position, it.ns, beta)

        if self._has_emitters:
            prim = np.asarray(hits.prim, dtype=np.int64)
            emitted = self._emitted(prim, d, it.ng, it.uv)
            wavefront.add_emitter_hits(
                radiance, idx, beta, emitted, prim, _f64(hits.t), d, it.ng,
                self.lights.area_pdf, paths.prev_pdf, paths.prev_delta,
            )  # fmt: skip

        if segment == max_depth:
            return paths.take(np.zeros(0, np.int64)), 0

        sh = self._shade(it, hits, d, self._footprint(hits, it, d, paths.spread))
        uniforms = surface_uniforms(rng, idx, segment)
        u_select, u_light, u_bsdf, u_lobe, u_roulette = wavefront.vertex_uniforms(uniforms)

        shadow_rays = self._next_event(idx, sh, beta, u_select, u_light, radiance, observer)

        sampled = sample_bsdf(sh.surf, sh.wo_local, u_bsdf, u_lobe)
        n_idx, o, wi, n_beta, eta2, pdf, delta = wavefront.next_paths(
            idx, beta, paths.eta2, _sampled(sampled), (sh.fs, sh.ft, sh.ns), sh.position, sh.ng, sh.scale,
            u_roulette, roulette,
        )  # fmt: skip
        zeros = np.zeros(len(n_idx))
        return _Paths(n_idx, o, wi, n_beta, eta2, pdf, delta, zeros, zeros.copy()), shadow_rays

    def _scatter_in_aggregate(
        self,
        paths: _Paths,
        events: AggregateEvents,
        segment: int,
        max_depth: int,
        roulette: bool,
        rng,
        radiance: np.ndarray,
        observer: PathObserver | None,
    ) -> _Scattered:
        """At voxels the aggregate scatters in: light sampling weighted by the voxel's throughput (MIS with
        the uniform direction sampling below; beyond Weier et al., switchable), then a uniform direction
        with weight throughput / pdf, Russian roulette where `roulette`. The continuing ray starts at the
        voxel's entry point."""
        n = len(paths.idx)
        if n == 0:
            return _Scattered(paths, 0)
        position = paths.o + events.t[:, None] * paths.d
        if observer is not None:
            observer.on_aggregate(paths.idx, position, events.voxel, paths.beta)
        if segment == max_depth:
            return _Scattered(paths.take(np.zeros(0, np.int64)), 0)
        wo = -paths.d
        u = rng.random((n, 6))
        wi = square_to_uniform_sphere(u[:, 3:5])
        shadow_rays = 0
        if self.aggregate_next_event and self.lights.count:
            ls = self.lights.sample(position, u[:, 0], u[:, 1:3])
            # One network query for both directions of every event.
            both = self.aggregate.throughput(
                np.concatenate([events.voxel, events.voxel]),
                np.concatenate([wo, wo]),
                np.concatenate([wi, ls.direction]),
            )
            phi = both[:n]
            shadow_rays = self._next_event_in_aggregate(
                paths, events, position, ls, both[n:], radiance, observer
            )
        else:
            phi = self.aggregate.throughput(events.voxel, wo, wi)
        t_min = self.aggregate.exit_distance(events.voxel, position, wi)
        pdf = np.full(n, UNIFORM_SPHERE_PDF)
        beta = paths.beta * phi / UNIFORM_SPHERE_PDF
        paths = _Paths(paths.idx, position, wi, beta, paths.eta2, pdf, np.zeros(n, bool), t_min, np.zeros(n))
        if roulette:
            keep = wavefront.roulette(beta, paths.eta2, np.ascontiguousarray(u[:, 5]))
        else:
            keep = np.flatnonzero(max3(beta) > 0)
        return _Scattered(paths.take(keep), shadow_rays)

    def _next_event_in_aggregate(
        self,
        paths: _Paths,
        events: AggregateEvents,
        position,
        ls: LightSample,
        phi,
        radiance,
        observer: PathObserver | None,
    ) -> int:
        """Light samples `ls` from scattering voxels, weighted by the throughput `phi` towards them."""
        mis = np.where(ls.delta, 1.0, power_heuristic(ls.pdf, np.full(len(ls.pdf), UNIFORM_SPHERE_PDF)))
        scale = np.where(ls.pdf > 0, mis / np.maximum(ls.pdf, 1e-300), 0.0)
        contribution = paths.beta * phi * ls.radiance * scale[:, None]
        live = np.flatnonzero(max3(contribution) > 0)
        if len(live) == 0:
            return 0
        origin, direction, distance = position[live], ls.direction[live], ls.distance[live]
        margin = 2 * RAY_OFFSET * np.maximum(max3(np.abs(origin)), 1e-30)
        t_max = np.where(np.isfinite(distance), distance * (1 - 1e-5) - margin, np.inf)
        t_min = self.aggregate.exit_distance(events.voxel[live], origin, direction)
        blocked = self.rays.occluded(origin, direction, t_max)
        blocked |= self.aggregate.occluded(origin, direction, t_min, t_max)
        radiance[paths.idx[live]] += contribution[live] * ~blocked[:, None]
        if observer is not None:
            weight = paths.beta[live] * phi[live] * scale[live, None]
            _observe_environment_samples(observer, paths.idx[live], ls, live, weight, blocked)
        return len(live)

    def _occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """Shadow rays from surfaces: blocked by a surface or, when there is one, by the aggregate."""
        blocked = self.rays.occluded(origins, directions, t_max)
        if self.aggregate is not None:
            blocked |= self.aggregate.occluded(origins, directions, np.zeros(len(origins)), t_max)
        return blocked

    def shade(self, hits: Hits, origins: np.ndarray, directions: np.ndarray) -> Shading:
        """Surface points of `hits` ready for BSDF queries (for samplers that walk paths themselves)."""
        it = self._interaction(hits, origins, directions, self._needs_uv)
        return self._shade(it, hits, directions)

    def _shade(self, it: _Interaction, hits: Hits, d: np.ndarray, footprint=None) -> Shading:
        material_ids = it.material
        surf = self._surfaces(hits, material_ids, it.uv, footprint)
        ns = it.ns
        if self.materials.normal_mapped:
            ns = self.materials.perturb_normals(material_ids, it.uv, ns, self._tangents(hits))
        fs, ft, ns, wo_local = wavefront.shading_frames(_f64(d), _f64(ns), surf.two_sided)
        return Shading(it.position, it.ng, it.scale, surf, fs, ft, ns, wo_local)

    def _next_event(
        self, idx, sh: Shading, beta, u_select, u_light, radiance, observer: PathObserver | None
    ) -> int:
        """Add light-sampled direct lighting (MIS-weighted) at every vertex; returns shadow rays. Vertices
        with only delta lobes sample lights too and get nothing from them (`eval_bsdf` is 0 there, so they
        cast no shadow ray): cheaper than gathering the other rows apart."""
        if self.lights.count == 0:
            return 0
        rows = np.arange(len(idx))
        ls = self.lights.sample(sh.position, u_select, u_light)
        wi_local = wavefront.to_local_rows(rows, ls.direction, sh.fs, sh.ft, sh.ns)
        f_cos, bsdf_pdf = eval_bsdf(sh.surf, sh.wo_local, wi_local)
        lights = (ls.direction, ls.distance, ls.radiance, ls.pdf, ls.delta)
        live, contribution, origin, direction, t_max, light_scale = wavefront.shadow_rays(
            rows, beta, _f64(f_cos), _f64(bsdf_pdf), lights, sh.position, sh.ng, sh.scale
        )
        if len(live) == 0:
            return 0
        blocked = self._occluded(origin, direction, t_max)
        wavefront.add_unblocked(radiance, idx[live], contribution, blocked)
        if observer is not None:
            weight = beta[live] * f_cos[live] * light_scale[live, None]
            _observe_environment_samples(observer, idx[live], ls, live, weight, blocked)
        return len(live)


def _f64(a: np.ndarray) -> np.ndarray:
    """`a` as the C-contiguous float64 array the compiled kernels take (one signature each)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _sampled(sampled: tuple) -> tuple:
    """`sample_bsdf`'s (wi, weight, pdf, delta, eta) in the kernels' layout."""
    wi, weight, pdf, delta, eta = sampled
    return _f64(wi), _f64(weight), _f64(pdf), np.ascontiguousarray(delta, dtype=np.bool_), _f64(eta)


def _observe_environment_samples(
    observer: PathObserver, idx, ls: LightSample, rows: np.ndarray, weight: np.ndarray, blocked: np.ndarray
) -> None:
    """The unblocked light samples `ls[rows]` of the environment as escapes of paths `idx` with `weight`
    (what multiplies their radiance). The environment is the one light at infinite distance that is not
    a delta light."""
    escaped = np.flatnonzero(~blocked & ~ls.delta[rows] & np.isinf(ls.distance[rows]))
    if len(escaped):
        observer.on_escape(idx[escaped], ls.direction[rows[escaped]], weight[escaped])
