"""The per-pixel inputs of Eq. 4 from a 1-spp raycast (the G-buffer of Algorithm 1): position in the
hash grid's box, shading normal facing the viewer, reflected view direction w_r (world space) and the
GGX parameters rho = (kd, ks, sigma)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.render.integrator import PathTracer
from workers.render.sampling import dot

# kd from the base colour, ks as a constant or from the base colour, per material type; others: diffuse.
_LOBES = {
    "diffuse": (True, None),
    "plastic": (True, "fresnel"),
    "conductor": (False, "base"),
    "dielectric": (False, 1.0),
}


@dataclass
class SurfaceInputs:
    hit: np.ndarray  # (N,) bool: pixels whose camera ray meets geometry (the others are masked)
    position: np.ndarray  # (N, 3) world
    normal: np.ndarray  # (N, 3) unit, towards the camera
    reflected: np.ndarray  # (N, 3) unit, w_o mirrored about the normal
    kd: np.ndarray  # (N, 3)
    ks: np.ndarray  # (N, 3)
    roughness: np.ndarray  # (N,) GGX alpha, 1 for Lambertian
    object_id: np.ndarray  # (N,) scene object index, -1 where the ray escapes

    def take(self, rows: np.ndarray) -> SurfaceInputs:
        return SurfaceInputs(*(getattr(self, k)[rows] for k in self.__dataclass_fields__))

    def modelled(self, objects: np.ndarray) -> np.ndarray:
        """(N,) bool: pixels on one of `objects` (scene object indices), whose indirect light is learned."""
        return self.hit & np.isin(self.object_id, objects)

    def tensors(self, box: np.ndarray) -> dict[str, torch.Tensor]:
        """Network inputs (float32): position normalised to `box` (2, 3), directions, materials."""
        unit = (self.position - box[0]) / np.maximum(box[1] - box[0], 1e-12)
        arrays = {
            "position": unit,
            "normal": self.normal,
            "reflected": self.reflected,
            "kd": self.kd,
            "ks": self.ks,
            "roughness": self.roughness[:, None],
        }
        return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in arrays.items()}


def material_lobes(tracer: PathTracer) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scene material: kd comes from the base colour (bool), ks comes from it (bool), constant ks."""
    from_base_kd, from_base_ks, constant_ks = [], [], []
    for material in tracer.scene.materials:
        kd, ks = _LOBES.get(material.type, (True, None))
        from_base_kd.append(kd)
        from_base_ks.append(ks == "base")
        if ks == "fresnel":
            constant_ks.append(((material.ior - 1) / (material.ior + 1)) ** 2)
        else:
            constant_ks.append(ks if isinstance(ks, float) else 0.0)
    return np.array(from_base_kd), np.array(from_base_ks), np.array(constant_ks)


def surface_inputs(tracer: PathTracer, origins: np.ndarray, directions: np.ndarray) -> SurfaceInputs:
    rec = tracer.first_hits(origins, directions)
    wo = -directions
    normal = np.where((dot(rec.shading_normal, wo) < 0)[:, None], -rec.shading_normal, rec.shading_normal)
    reflected = 2 * dot(normal, wo)[:, None] * normal - wo
    reflected /= np.maximum(np.linalg.norm(reflected, axis=1, keepdims=True), 1e-12)
    kd_base, ks_base, ks_constant = material_lobes(tracer)
    material = np.maximum(rec.material_id, 0)
    kd = rec.albedo * kd_base[material][:, None]
    ks = np.where(ks_base[material][:, None], rec.albedo, ks_constant[material][:, None])
    hit = rec.hit
    zero = ~hit
    for array in (normal, reflected, kd, ks):
        array[zero] = 0.0
    roughness = np.where(hit, rec.roughness, 0.0)
    return SurfaceInputs(hit, rec.position, normal, reflected, kd, ks, roughness, rec.object_id)
