"""Next-event estimation: one discrete distribution over every light, proportional to its power.

Entries are emissive triangles (power pi A L, twice for two-sided), point lights (4 pi I; spot lights
2 pi (1 - cos outer) I, the point lights' cone, with glTF's falloff `spot_falloff`),
directional lights (E pi R^2) and the environment (4 pi^2 R^2 L_mean), with R the scene's
bounding-sphere radius: power-proportional selection keeps shadow rays where the light is.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from workers.render.environment import ConstantEnvironment, EnvironmentMapLight
from workers.render.sampling import (
    luminance,
    normalize,
    select_where,
    selection_size,
    square_to_uniform_triangle,
)
from workers.scene import spec
from workers.scene.compile import CompiledScene

TRIANGLE, POINT, DIRECTIONAL, ENVIRONMENT = 0, 1, 2, 3


def spot_falloff(cos_axis: np.ndarray, cones: np.ndarray) -> np.ndarray:
    """glTF's (KHR_lights_punctual) spot attenuation: clamp((cos - cos_outer) / (cos_inner - cos_outer))^2;
    1 for point lights, whose cone covers every direction."""
    cos_inner, cos_outer = cones[:, 0], cones[:, 1]
    t = np.clip((cos_axis - cos_outer) / np.maximum(cos_inner - cos_outer, 1e-3), 0.0, 1.0)
    return np.where(cos_outer < -1.0, 1.0, t * t)


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

    def sample(self, p: np.ndarray, u_select: np.ndarray, u: np.ndarray) -> LightSample:
        """Pick a light for each shading point p (N, 3) and a point or direction on it."""
        n = len(p)
        direction, distance = np.zeros((n, 3)), np.full(n, np.inf)
        radiance, pdf, delta = np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool)
        if self.count == 0 or n == 0:
            return LightSample(direction, distance, radiance, pdf, delta)
        entry = np.minimum(np.searchsorted(self.cdf, u_select, side="right"), self.count - 1)
        kind, which, select = self.kinds[entry], self.index[entry], self.prob[entry]

        sel = select_where(kind == TRIANGLE)
        if selection_size(sel, n):
            tri = which[sel]
            b = square_to_uniform_triangle(u[sel])
            d = self._origin[tri] + b[:, :1] * self._edge1[tri] + b[:, 1:] * self._edge2[tri] - p[sel]
            dist = np.sqrt(np.einsum("ij,ij->i", d, d))
            d /= np.maximum(dist, 1e-300)[:, None]
            cos_l = -np.einsum("ij,ij->i", d, self._normals[tri])
            facing = (cos_l > 0) | self.scene.two_sided_emission[tri]
            cos_abs = np.abs(cos_l)
            ok = facing & (cos_abs > 1e-12) & (dist > 0)
            direction[sel], distance[sel] = d, dist
            radiance[sel] = self._emission[tri] * ok[:, None]
            if self.emission_scale is not None:
                uvs = self.scene.uvs[tri].astype(np.float64)
                uv = uvs[:, 0] + b[:, :1] * (uvs[:, 1] - uvs[:, 0]) + b[:, 1:] * (uvs[:, 2] - uvs[:, 0])
                radiance[sel] *= self.emission_scale(self.scene.material_ids[tri], uv)
            pdf[sel] = np.where(
                ok, select[sel] / self.scene.areas[tri] * dist**2 / np.maximum(cos_abs, 1e-300), 0.0
            )

        sel = select_where(kind == POINT)
        if selection_size(sel, n):
            d = self.point_position[which[sel]] - p[sel]
            dist = np.linalg.norm(d, axis=1)
            direction[sel] = d / np.maximum(dist, 1e-300)[:, None]
            distance[sel] = dist
            falloff = spot_falloff(
                -np.einsum("ij,ij->i", direction[sel], self.point_axis[which[sel]]),
                self.point_cones[which[sel]],
            )
            radiance[sel] = (
                self.point_intensity[which[sel]] * (falloff / np.maximum(dist**2, 1e-300))[:, None]
            )
            pdf[sel], delta[sel] = select[sel], True

        sel = select_where(kind == DIRECTIONAL)
        if selection_size(sel, n):
            direction[sel] = self.dir_to_light[which[sel]]
            radiance[sel] = self.dir_irradiance[which[sel]]
            pdf[sel], delta[sel] = select[sel], True

        sel = select_where(kind == ENVIRONMENT)
        if selection_size(sel, n):
            d, env_pdf = self.environment.sample(u[sel])
            direction[sel] = d
            radiance[sel] = self.environment.radiance(d) * (env_pdf > 0)[:, None]
            pdf[sel] = select[sel] * env_pdf
        return LightSample(direction, distance, radiance, pdf, delta)

    def pdf_hit_emitter(self, prim: np.ndarray, distance: np.ndarray, cos_light: np.ndarray) -> np.ndarray:
        """Solid-angle pdf with which `sample` would have produced a BSDF-sampled hit on an emitter."""
        return self.area_pdf[prim] * distance**2 / np.maximum(np.abs(cos_light), 1e-300)

    def pdf_environment(self, directions: np.ndarray) -> np.ndarray:
        if self.environment is None or self.env_prob == 0:
            return np.zeros(len(directions))
        return self.env_prob * self.environment.pdf(directions)
