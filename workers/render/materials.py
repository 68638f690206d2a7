"""Material parameters by triangle: the scene's materials as arrays, textures looked up by UV."""

from __future__ import annotations

import numpy as np

from workers.render.bsdf import Kind, SurfaceBatch
from workers.scene import spec
from workers.scene.compile import CompiledScene
from workers.scene.textures import evaluate_texture, load_image_texture

_KIND = {
    spec.Diffuse: Kind.DIFFUSE,
    spec.Conductor: Kind.CONDUCTOR,
    spec.Plastic: Kind.PLASTIC,
    spec.Dielectric: Kind.DIELECTRIC,
}


def _base_colour(material: spec.Material):
    match material:
        case spec.Diffuse():
            return material.reflectance
        case spec.Conductor():
            return material.specular
        case spec.Plastic():
            return material.diffuse
        case _:
            return (1.0, 1.0, 1.0)


class MaterialTable:
    def __init__(self, scene: CompiledScene):
        materials = scene.materials
        self.kind = np.array([_KIND[type(m)] for m in materials], dtype=np.int8)
        self.alpha = np.array([getattr(m, "roughness", 0.0) for m in materials], dtype=np.float64)
        if (self.kind == Kind.DIFFUSE).any():
            self.alpha[self.kind == Kind.DIFFUSE] = 1.0  # reported roughness of a Lambertian surface
        self.ior = np.array([getattr(m, "ior", 1.5) for m in materials], dtype=np.float64)
        self.base = np.zeros((len(materials), 3))
        self.textures: dict[int, tuple[spec.Texture, np.ndarray | None]] = {}
        for i, (name, m) in enumerate(zip(scene.material_names, materials, strict=True)):
            colour = _base_colour(m)
            if isinstance(colour, tuple):
                self.base[i] = colour
            else:
                field = f"materials.{name}"
                image = load_image_texture(colour, field, scene.base_dir) if colour.type == "image" else None
                self.textures[i] = (colour, image)

    def surfaces(self, material_ids: np.ndarray, uv: np.ndarray) -> SurfaceBatch:
        base = self.base[material_ids]
        for i, (texture, image) in self.textures.items():
            sel = np.flatnonzero(material_ids == i)
            if len(sel):
                base[sel] = evaluate_texture(texture, image, uv[sel])
        alpha = np.where(self.kind[material_ids] == Kind.DIFFUSE, 0.0, self.alpha[material_ids])
        return SurfaceBatch(self.kind[material_ids], base, alpha, self.ior[material_ids])

    def roughness(self, material_ids: np.ndarray) -> np.ndarray:
        return self.alpha[material_ids]
