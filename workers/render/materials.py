"""Material parameters by scene material id: the scene's materials as arrays, textures looked up by UV.

Each scene material is shaded by the BSDF family registered under its `type` (`workers.render.bsdf`; an
aggregate material's surfaces by its `base`, `workers.render.aggregate_materials`);
the family says what the material contributes to a `SurfaceBatch`, and which of its parameters are
textured (`BSDF.textures`). Two texture slots mean the same for every family and are handled here: `normal`
(a tangent-space normal map, glTF's convention: linear, +Y towards the image's top, unpacked as
2 texel - 1 with x and y scaled by the material's `normal_scale`) bends the shading normal, and `emission`
scales the radiance of the emitting objects that use the material.
"""

from __future__ import annotations

import numpy as np

import workers.render.bsdfs  # noqa: F401  (registers the built-in families)
from workers.render.bsdf import SurfaceBatch, bsdf_code, bsdf_family
from workers.render.jit import njit
from workers.scene.format import spec
from workers.scene.geometry.compile import CompiledScene
from workers.scene.importers.textures import MipChain, evaluate_texture, load_image_texture

SHADING_SLOTS = frozenset({"normal", "emission"})  # read by the renderer, not by the BSDF family


class MaterialTable:
    def __init__(self, scene: CompiledScene):
        materials = [spec.surface_material(m) for m in scene.materials]
        self._materials = materials
        parameters = [bsdf_family(m.type).parameters(m) for m in materials]
        self.family = np.array([bsdf_code(m.type) for m in materials], dtype=np.int8)
        self.alpha = np.array([p.alpha for p in parameters], dtype=np.float64)
        self.ior = np.array([p.ior for p in parameters], dtype=np.float64)
        self._roughness = np.array([p.roughness for p in parameters], dtype=np.float64)
        self.extra = np.zeros((len(materials), max([len(p.extra) for p in parameters], default=0)))
        for i, p in enumerate(parameters):
            self.extra[i, : len(p.extra)] = p.extra
        self.base = np.zeros((len(materials), 3))
        self.textures: dict[int, tuple[spec.Texture, MipChain | None]] = {}
        for i, (name, p) in enumerate(zip(scene.material_names, parameters, strict=True)):
            if isinstance(p.base, tuple):
                self.base[i] = p.base
            else:
                field = f"materials.{name}"
                image = _mip_chain(p.base, field, scene)
                self.textures[i] = (p.base, image)
        self.slots: dict[int, dict[str, tuple[spec.Texture, np.ndarray | None]]] = {}
        for i, (name, m) in enumerate(zip(scene.material_names, materials, strict=True)):
            slots = bsdf_family(m.type).textures(m)
            if slots:
                self.slots[i] = {
                    slot: (t, _mip_chain(t, f"materials.{name}.{slot}_texture", scene))
                    for slot, t in slots.items()
                }

    def surfaces(self, material_ids: np.ndarray, uv: np.ndarray, footprint: np.ndarray | None = None):
        """The rows' SurfaceBatch; image textures are filtered over `footprint` (log2 UV width per row,
        `MipChain.lookup`) where it is given."""
        family, base, alpha, ior, extra = _gather(
            np.asarray(material_ids, np.int64), self.family, self.base, self.alpha, self.ior, self.extra
        )
        for i, (texture, image) in self.textures.items():
            sel = np.flatnonzero(material_ids == i)
            if len(sel):
                base[sel] = evaluate_texture(texture, image, uv[sel], _rows(footprint, sel))
        batch = SurfaceBatch(family, base, alpha, ior, extra if self.extra.shape[1] else None)
        for i, slots in self.slots.items():
            sel = np.flatnonzero(material_ids == i)
            if len(sel):
                lookups = {
                    slot: evaluate_texture(t, image, uv[sel], _rows(footprint, sel))
                    for slot, (t, image) in slots.items()
                    if slot not in SHADING_SLOTS
                }
                if not lookups:
                    continue
                rows = batch.take(sel)
                bsdf_family(self._materials[i].type).apply_textures(self._materials[i], rows, lookups)
                batch.assign(sel, rows)
        return batch

    def _slot(self, name: str) -> dict[int, tuple[spec.Texture, MipChain | None]]:
        return {i: slots[name] for i, slots in self.slots.items() if name in slots}

    @property
    def normal_mapped(self) -> bool:
        return bool(self._slot("normal"))

    def perturb_normals(self, material_ids, uv, ns: np.ndarray, tangents: np.ndarray) -> np.ndarray:
        """Shading normals bent by the normal maps of `material_ids`; `tangents` (N, 4) at the points."""
        ns = ns.copy()
        for i, (texture, image) in self._slot("normal").items():
            sel = np.flatnonzero(material_ids == i)
            if not len(sel):
                continue
            local = 2.0 * evaluate_texture(texture, image, uv[sel]).astype(np.float64) - 1.0
            local[:, :2] *= getattr(self._materials[i], "normal_scale", 1.0)
            n = ns[sel]
            t = tangents[sel, :3] - n * np.einsum("ij,ij->i", tangents[sel, :3], n)[:, None]
            t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
            b = np.cross(n, t) * np.where(tangents[sel, 3:] < 0, -1.0, 1.0)
            bent = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:] * n
            length = np.linalg.norm(bent, axis=1, keepdims=True)
            ns[sel] = np.where(length > 1e-12, bent / np.maximum(length, 1e-300), n)
        return ns

    def emission_scale(self, material_ids: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(N, 3) factors the emission textures apply to emitted radiance (1 without one)."""
        scale = np.ones((len(material_ids), 3))
        for i, (texture, image) in self._slot("emission").items():
            sel = np.flatnonzero(material_ids == i)
            if len(sel):
                scale[sel] = evaluate_texture(texture, image, uv[sel])
        return scale

    @property
    def emission_textured(self) -> bool:
        return bool(self._slot("emission"))

    @property
    def needs_uv(self) -> bool:
        """Whether any material reads a texture (hits then need their UVs)."""
        return bool(self.textures or self.slots)

    def roughness(self, material_ids: np.ndarray) -> np.ndarray:
        """Roughness for the AOV: the GGX alpha, and 1 for Lambertian surfaces."""
        return self._roughness[material_ids]


@njit(cache=True, nogil=True, fastmath=False)
def _gather(material_ids, family, base, alpha, ior, extra):
    """The material table's rows of `material_ids`, in one pass (five NumPy gathers took 4% of a render)."""
    n, k = len(material_ids), extra.shape[1]
    out_family, out_base = np.empty(n, np.int8), np.empty((n, 3))
    out_alpha, out_ior, out_extra = np.empty(n), np.empty(n), np.empty((n, k))
    for i in range(n):
        m = material_ids[i]
        out_family[i], out_alpha[i], out_ior[i] = family[m], alpha[m], ior[m]
        for c in range(3):
            out_base[i, c] = base[m, c]
        for c in range(k):
            out_extra[i, c] = extra[m, c]
    return out_family, out_base, out_alpha, out_ior, out_extra


def _mip_chain(texture: spec.Texture, field: str, scene: CompiledScene) -> MipChain | None:
    """The loaded image of an image texture with its mip levels; None for procedural textures."""
    if texture.type != "image":
        return None
    return MipChain(load_image_texture(texture, field, scene.base_dir))


def _rows(footprint: np.ndarray | None, rows: np.ndarray) -> np.ndarray | None:
    return None if footprint is None else footprint[rows]
