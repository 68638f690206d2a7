"""Next-event estimation: one discrete distribution over every light, proportional to its power.

Entries are emissive triangles (power pi A L, twice for two-sided), point lights (4 pi I; spot lights
2 pi (1 - cos outer) I, the point lights' cone, with glTF's falloff `spot_falloff`),
directional lights (E pi R^2) and the environment (4 pi^2 R^2 L_mean), with R the scene's
bounding-sphere radius: power-proportional selection keeps shadow rays where the light is.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from workers.render import kernels
from workers.render.environment import NO_MAP, ConstantEnvironment, EnvironmentMapLight, sample_rows
from workers.render.jit import njit
from workers.render.sampling import luminance, normalize
from workers.scene.format import spec
from workers.scene.geometry.compile import CompiledScene

TRIANGLE, POINT, DIRECTIONAL, ENVIRONMENT = 0, 1, 2, 3


@kernels.scalar
def _falloff(cos_axis, cos_inner, cos_outer):
    if cos_outer < -1.0:
        return 1.0
    t = min(max((cos_axis - cos_outer) / max(cos_inner - cos_outer, 1e-3), 0.0), 1.0)
    return t * t


@njit(cache=True, nogil=True, fastmath=False)
def spot_falloff(cos_axis: np.ndarray, cones: np.ndarray) -> np.ndarray:
    """glTF's (KHR_lights_punctual) spot attenuation: clamp((cos - cos_outer) / (cos_inner - cos_outer))^2
    per row of `cones` (cos inner, cos outer); 1 for point lights, whose cone covers every direction."""
    out = np.empty(len(cos_axis))
    for i in range(len(cos_axis)):
        out[i] = _falloff(cos_axis[i], cones[i, 0], cones[i, 1])
    return out


@dataclass
class LightSample:
    direction: np.ndarray  # (N, 3) unit, from the shading point to the light
    distance: np.ndarray  # (N,) inf for the environment and directional lights
    radiance: np.ndarray  # (N, 3) radiance arriving (irradiance for delta lights)
    pdf: np.ndarray  # (N,) solid-angle pdf incl. selection; for delta lights the selection probability
    delta: np.ndarray  # (N,) bool: point or directional light (no MIS)


class LightSampler:
    def __init__(self, scene: CompiledScene, emission_scale: Callable | None = None):
        """`emission_scale(material_ids, uv)` is what emission textures multiply a triangle's radiance by
        (`MaterialTable.emission_scale`); selection stays proportional to the untextured power."""
        self.scene = scene
        self.emission_scale = emission_scale
        corners = scene.positions.astype(np.float64)
        self._origin, self._edge1, self._edge2 = (
            corners[:, 0],
            corners[:, 1] - corners[:, 0],
            corners[:, 2] - corners[:, 0],
        )
        self._normals = scene.geometric_normals.astype(np.float64)
        self._emission = scene.emission.astype(np.float64)
        bounds = scene.bounds
        self.center = 0.5 * (bounds[0] + bounds[1])
        self.radius = max(0.5 * scene.extent, 1e-12)
        env = scene.spec.environment
        self.environment: EnvironmentMapLight | ConstantEnvironment | None = None
        if scene.environment_image is not None:
            self.environment = EnvironmentMapLight(scene.environment_image, scene.environment_rotation)
        elif isinstance(env, spec.ConstantBackground):
            self.environment = ConstantEnvironment(env.radiance)

        emissive = np.flatnonzero(luminance(scene.emission.astype(np.float64)) > 0)
        sides = np.where(scene.two_sided_emission[emissive], 2.0, 1.0)
        tri_power = (
            np.pi * scene.areas[emissive] * luminance(scene.emission[emissive].astype(np.float64)) * sides
        )
        self.points = [l for l in scene.spec.lights if isinstance(l, spec.PointLight | spec.SpotLight)]
        self.directionals = [l for l in scene.spec.lights if isinstance(l, spec.DirectionalLight)]
        spots = [l if isinstance(l, spec.SpotLight) else None for l in self.points]
        self.point_axis = np.array(
            [(0.0, 0.0, 0.0) if l is None else l.direction for l in spots], dtype=np.float64
        ).reshape(-1, 3)
        self.point_axis /= np.maximum(np.linalg.norm(self.point_axis, axis=1, keepdims=True), 1e-300)
        self.point_cones = np.array(
            [(-2.0, -1.0) if l is None else np.cos(np.radians([l.inner_cone, l.outer_cone])) for l in spots]
        ).reshape(-1, 2)  # (cos inner, cos outer); a point light's cone covers every direction
        point_power = [
            2 * np.pi * (1 - cos_outer) * luminance(np.asarray(l.intensity))
            for l, (_, cos_outer) in zip(self.points, self.point_cones, strict=True)
        ]
        dir_power = [luminance(np.asarray(l.irradiance)) * np.pi * self.radius**2 for l in self.directionals]
        env_power = []
        if self.environment is not None:
            env_power = [4 * np.pi**2 * self.radius**2 * self.environment.mean_radiance]
        kinds = np.concatenate(
            [
                np.full(len(emissive), TRIANGLE),
                np.full(len(self.points), POINT),
                np.full(len(self.directionals), DIRECTIONAL),
                np.full(len(env_power), ENVIRONMENT),
            ]
        ).astype(np.int8)
        index = np.concatenate(
            [
                emissive,
                np.arange(len(self.points)),
                np.arange(len(self.directionals)),
                np.zeros(len(env_power), int),
            ]
        ).astype(np.int64)
        power = np.concatenate([tri_power, point_power, dir_power, env_power]).astype(np.float64)
        keep = power > 0
        self.kinds, self.index, power = kinds[keep], index[keep], power[keep]
        self.total_power = float(power.sum())
        self.count = len(power)
        self.prob = power / self.total_power if self.count else power
        self.cdf = np.cumsum(self.prob)
        if self.count:
            self.cdf[-1] = 1.0
        # Probability density per unit area of picking a point on an emissive triangle (for MIS).
        self.area_pdf = np.zeros(scene.num_triangles)
        tri = self.kinds == TRIANGLE
        self.area_pdf[self.index[tri]] = self.prob[tri] / scene.areas[self.index[tri]]
        env_entries = np.flatnonzero(self.kinds == ENVIRONMENT)
        self.env_prob = float(self.prob[env_entries[0]]) if len(env_entries) else 0.0
        self.point_position = np.array([l.position for l in self.points], dtype=np.float64).reshape(-1, 3)
        self.point_intensity = np.array([l.intensity for l in self.points], dtype=np.float64).reshape(-1, 3)
        self.dir_to_light = -normalize(
            np.array([l.direction for l in self.directionals], float).reshape(-1, 3)
        )
        self.dir_irradiance = np.array([l.irradiance for l in self.directionals], dtype=np.float64).reshape(
            -1, 3
        )
        self._tables = _LightTables(
            self.cdf,
            self.kinds,
            self.index,
            self.prob,
            self._origin,
            self._edge1,
            self._edge2,
            self._normals,
            self._emission,
            np.ascontiguousarray(scene.two_sided_emission, dtype=np.bool_),
            np.ascontiguousarray(scene.areas, dtype=np.float64),
            self.point_position,
            self.point_intensity,
            self.point_axis,
            np.ascontiguousarray(self.point_cones, dtype=np.float64),
            np.ascontiguousarray(self.dir_to_light, dtype=np.float64),
            self.dir_irradiance,
        )

    def sample(self, p: np.ndarray, u_select: np.ndarray, u: np.ndarray) -> LightSample:
        """Pick a light for each shading point p (N, 3) and a point or direction on it: one compiled pass
        over the rows, lat-long maps included; then in NumPy the rows of another kind of environment (it is
        replaceable: `workers.models.prt.lighting`) and textured emission (lookups into images)."""
        n = len(p)
        if self.count == 0 or n == 0:
            return LightSample(
                np.zeros((n, 3)), np.full(n, np.inf), np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool)
            )
        env = self.environment
        env_map = env.tables if isinstance(env, EnvironmentMapLight) else NO_MAP
        direction, distance, radiance, pdf, delta, kind, tri, b = _sample_lights(
            np.ascontiguousarray(p, dtype=np.float64),
            np.ascontiguousarray(u_select, dtype=np.float64),
            np.ascontiguousarray(u, dtype=np.float64),
            self._tables,
            env_map,
        )
        if env is not None and env_map is NO_MAP:
            sel = np.flatnonzero(kind == ENVIRONMENT)
            if len(sel):
                d, env_pdf = env.sample(u[sel])
                direction[sel] = d
                radiance[sel] = env.radiance(d) * (env_pdf > 0)[:, None]
                pdf[sel] *= env_pdf
        if self.emission_scale is not None:
            sel = np.flatnonzero(kind == TRIANGLE)
            if len(sel):
                uvs = self.scene.uvs[tri[sel]].astype(np.float64)
                bs = b[sel]
                uv = uvs[:, 0] + bs[:, :1] * (uvs[:, 1] - uvs[:, 0]) + bs[:, 1:] * (uvs[:, 2] - uvs[:, 0])
                radiance[sel] *= self.emission_scale(self.scene.material_ids[tri[sel]], uv)
        return LightSample(direction, distance, radiance, pdf, delta)

    def pdf_hit_emitter(self, prim: np.ndarray, distance: np.ndarray, cos_light: np.ndarray) -> np.ndarray:
        """Solid-angle pdf with which `sample` would have produced a BSDF-sampled hit on an emitter."""
        return self.area_pdf[prim] * distance**2 / np.maximum(np.abs(cos_light), 1e-300)

    def environment_lookup(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radiance of the environment along world directions (0 without one) and the solid-angle pdf with
        which `sample` draws them (selection included), in one pass where the environment offers one."""
        n = len(directions)
        env = self.environment
        if env is None:
            return np.zeros((n, 3)), np.zeros(n)
        if isinstance(env, EnvironmentMapLight | ConstantEnvironment):
            radiance, pdf = env.radiance_and_pdf(directions)
        else:
            radiance, pdf = env.radiance(directions), env.pdf(directions)
        return radiance, pdf * self.env_prob


class _LightTables(NamedTuple):
    """The light list as the arrays `_sample_lights` reads (a tuple: one typed argument)."""

    cdf: np.ndarray
    kinds: np.ndarray
    index: np.ndarray
    prob: np.ndarray
    tri_origin: np.ndarray
    tri_edge1: np.ndarray
    tri_edge2: np.ndarray
    tri_normal: np.ndarray
    tri_emission: np.ndarray
    two_sided: np.ndarray
    areas: np.ndarray
    point_position: np.ndarray
    point_intensity: np.ndarray
    point_axis: np.ndarray
    point_cones: np.ndarray
    dir_to_light: np.ndarray
    dir_irradiance: np.ndarray


@njit(cache=True, nogil=True, fastmath=False)
def _sample_lights(p, u_select, u, lights, env):
    """Triangle, point, directional and environment light samples per row, the environment from the
    lat-long map `env`; without one (`NO_MAP`) environment rows get their selection probability in `pdf`
    and are finished by the caller. Also returns per row the light kind, the triangle and its barycentrics
    (for emission textures)."""
    n = len(p)
    direction, distance = np.zeros((n, 3)), np.full(n, np.inf)
    radiance, pdf, delta = np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.bool_)
    kind, tri, bary = np.empty(n, np.int8), np.zeros(n, np.int64), np.zeros((n, 2))
    cdf = lights.cdf
    count = len(cdf)
    env_rows, env_count = np.empty(n, np.int64), 0  # sampled after the loop, in blocks (`sample_rows`)
    for i in range(n):
        entry = min(kernels.search_right(cdf, u_select[i]), count - 1)
        k, which, select = lights.kinds[entry], lights.index[entry], lights.prob[entry]
        kind[i] = k
        if k == TRIANGLE:
            u0, u1 = u[i, 0], u[i, 1]  # Heitz's low-distortion split
            if u1 > u0:
                b0, b1 = u0 / 2, u1 - u0 / 2
            else:
                b0, b1 = u0 - u1 / 2, u1 / 2
            tri[i], bary[i, 0], bary[i, 1] = which, b0, b1
            o, e1, e2 = lights.tri_origin[which], lights.tri_edge1[which], lights.tri_edge2[which]
            dx = o[0] + b0 * e1[0] + b1 * e2[0] - p[i, 0]
            dy = o[1] + b0 * e1[1] + b1 * e2[1] - p[i, 1]
            dz = o[2] + b0 * e1[2] + b1 * e2[2] - p[i, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            inv = 1.0 / max(dist, 1e-300)
            dx, dy, dz = dx * inv, dy * inv, dz * inv
            nrm = lights.tri_normal[which]
            cos_l = -(dx * nrm[0] + dy * nrm[1] + dz * nrm[2])
            direction[i, 0], direction[i, 1], direction[i, 2] = dx, dy, dz
            distance[i] = dist
            if (cos_l > 0 or lights.two_sided[which]) and abs(cos_l) > 1e-12 and dist > 0:
                for c in range(3):
                    radiance[i, c] = lights.tri_emission[which, c]
                pdf[i] = select / lights.areas[which] * dist * dist / max(abs(cos_l), 1e-300)
        elif k == POINT:
            pos = lights.point_position[which]
            dx, dy, dz = pos[0] - p[i, 0], pos[1] - p[i, 1], pos[2] - p[i, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            inv = 1.0 / max(dist, 1e-300)
            dx, dy, dz = dx * inv, dy * inv, dz * inv
            direction[i, 0], direction[i, 1], direction[i, 2] = dx, dy, dz
            distance[i] = dist
            axis, cones = lights.point_axis[which], lights.point_cones[which]
            falloff = _falloff(-(dx * axis[0] + dy * axis[1] + dz * axis[2]), cones[0], cones[1])
            scale = falloff / max(dist * dist, 1e-300)
            for c in range(3):
                radiance[i, c] = lights.point_intensity[which, c] * scale
            pdf[i], delta[i] = select, True
        elif k == DIRECTIONAL:
            for c in range(3):
                direction[i, c] = lights.dir_to_light[which, c]
                radiance[i, c] = lights.dir_irradiance[which, c]
            pdf[i], delta[i] = select, True
        else:
            pdf[i] = select
            env_rows[env_count] = i
            env_count += 1
    if env.image.shape[0] > 0:
        sample_rows(u, env_rows[:env_count], env, direction, pdf, radiance)
    return direction, distance, radiance, pdf, delta, kind, tri, bary
