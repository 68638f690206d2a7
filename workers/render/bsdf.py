"""BSDFs as plugins registered by name, evaluated and sampled over batches mixing them (wavefront style).

A BSDF family (`diffuse`, `conductor`, ...; the built-in ones are in `workers.render.bsdfs`) subclasses
`BSDF` and registers with `@register_material("name")`; the scene's materials map to families by their
`type`. Batches carry a family code per row: `eval_bsdf` and `sample_bsdf` hand each family the rows of
its own kind (vectorised NumPy) and scatter the results back, so a new family needs no dispatch table.

Conventions, in the local shading frame (z = normal): `wo` points to the camera (or previous vertex),
`wi` towards the light; both unit. `eval` returns f(wo, wi) * |cos(wi)| and the solid-angle pdf of
`sample` producing wi; delta lobes are never returned by `eval`. `sample` returns wi, the weight
f |cos| / pdf (what a path's throughput is multiplied by), the pdf (0 for delta lobes) and a delta flag.
Transmission carries the 1/eta^2 radiance scaling. Two-sided families see wo.z > 0 (the caller flips the
frame); the others (dielectrics) see both sides and use the sign of wo.z to know which side they are on.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from workers.scene.spec import ColorOrTexture


@dataclass
class SurfaceBatch:
    """Material parameters at N shading points."""

    family: np.ndarray  # (N,) int8 code of a registered BSDF family (`bsdf_code`)
    base: np.ndarray  # (N, 3): diffuse reflectance, or conductor specular colour
    alpha: np.ndarray  # (N,) GGX alpha; 0 means perfectly smooth
    ior: np.ndarray  # (N,) interior over exterior
    extra: np.ndarray | None = None  # (N, K) family-specific parameters (`MaterialParameters.extra`)

    def take(self, idx: np.ndarray) -> SurfaceBatch:
        extra = None if self.extra is None else self.extra[idx]
        return SurfaceBatch(self.family[idx], self.base[idx], self.alpha[idx], self.ior[idx], extra)

    def assign(self, idx: np.ndarray, rows: SurfaceBatch) -> None:
        """Write `rows` (a batch of len(idx) rows, e.g. after textures changed them) back at `idx`."""
        self.base[idx], self.alpha[idx], self.ior[idx] = rows.base, rows.alpha, rows.ior
        if self.extra is not None and rows.extra is not None:
            self.extra[idx, : rows.extra.shape[1]] = rows.extra

    @property
    def is_delta(self) -> np.ndarray:
        """Surfaces with only delta lobes, for which next-event estimation is pointless."""
        return (self.alpha <= 0) & _registry.delta_when_smooth[self.family]

    @property
    def two_sided(self) -> np.ndarray:
        """Surfaces that look the same from both sides (the shading frame is flipped towards wo)."""
        return _registry.two_sided[self.family]


@dataclass(frozen=True)
class MaterialParameters:
    """What a scene material contributes to `SurfaceBatch` rows, and its roughness for the AOV."""

    base: ColorOrTexture = (1.0, 1.0, 1.0)
    alpha: float = 0.0
    ior: float = 1.5
    roughness: float = 0.0  # reported in the `roughness` AOV (1 for a Lambertian surface)
    extra: tuple[float, ...] = ()  # the family's own per-row parameters (`SurfaceBatch.extra`)


class BSDF(ABC):
    """A family of BSDFs over `SurfaceBatch` rows of its own code (module docstring: conventions)."""

    two_sided: ClassVar[bool] = True
    delta_when_smooth: ClassVar[bool] = False  # alpha = 0 leaves only delta lobes (no light sampling)

    @abstractmethod
    def parameters(self, material: Any) -> MaterialParameters:
        """The rows' parameters of a scene material (`workers.scene.spec`) of this family."""

    @abstractmethod
    def eval(self, s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f |cos theta_i| and the pdf of sampling wi, per row (local frames)."""

    @abstractmethod
    def sample(self, s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
        """wi, weight f |cos| / pdf, pdf and whether the sampled lobe is a delta, per row."""

    def textures(self, material: Any) -> dict[str, Any]:
        """The material's textured parameters by slot name (`workers.scene.spec` textures); none by default.
        The slots `normal` and `emission` are the renderer's (`workers.render.materials`)."""
        return {}

    def apply_textures(self, material: Any, s: SurfaceBatch, lookups: dict[str, np.ndarray]) -> None:  # noqa: B027
        """Overwrite the rows `s` of `material` with its textures' values `lookups` (slot -> (N, 3) RGB);
        a family without textures never receives any."""


class _Registry:
    """Families by name and by code; per-code flags as arrays so batches look them up with one gather."""

    def __init__(self) -> None:
        self.families: list[BSDF] = []
        self.codes: dict[str, int] = {}
        self.two_sided = np.zeros(0, bool)
        self.delta_when_smooth = np.zeros(0, bool)

    def add(self, name: str, family: BSDF) -> None:
        """Register `family` under `name`; registering a name again replaces it under the same code."""
        if name in self.codes:
            self.families[self.codes[name]] = family
        else:
            if len(self.families) == np.iinfo(np.int8).max:
                raise ValueError("too many BSDF families for an int8 code")
            self.codes[name] = len(self.families)
            self.families.append(family)
        self.two_sided = np.array([f.two_sided for f in self.families])
        self.delta_when_smooth = np.array([f.delta_when_smooth for f in self.families])


_registry = _Registry()


def register_material(name: str) -> Callable[[type[BSDF]], type[BSDF]]:
    """Class decorator: scene materials whose `type` is `name` are shaded by (an instance of) the class."""

    def decorate(cls: type[BSDF]) -> type[BSDF]:
        _registry.add(name, cls())
        return cls

    return decorate


def bsdf_code(name: str) -> int:
    """The code of the family registered as `name` (what `SurfaceBatch.family` holds)."""
    try:
        return _registry.codes[name]
    except KeyError:
        raise KeyError(f"no BSDF registered as {name!r}; registered: {sorted(_registry.codes)}") from None


def bsdf_family(name: str) -> BSDF:
    return _registry.families[bsdf_code(name)]


def contiguous(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays as C-contiguous float64, the one layout the families' compiled kernels are built for
    (callers pass slices such as `u[:, 3:5]`; one signature per kernel keeps the JIT cache small)."""
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in arrays)


def _groups(family: np.ndarray):
    """(family, indices) for each family present; a single family avoids any gather."""
    present = np.unique(family)
    if len(present) == 1:
        yield _registry.families[int(present[0])], None
        return
    for code in present:
        yield _registry.families[int(code)], np.flatnonzero(family == code)


def eval_bsdf(s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f(wo, wi) |cos wi| (N, 3) and the pdf of sampling wi (N,)."""
    n = len(wo)
    f_cos, pdf = np.zeros((n, 3)), np.zeros(n)
    for family, idx in _groups(s.family):
        if idx is None:
            return family.eval(s, wo, wi)
        f_cos[idx], pdf[idx] = family.eval(s.take(idx), wo[idx], wi[idx])
    return f_cos, pdf


def sample_bsdf(s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
    """Sample wi given wo, two uniforms `u` (N, 2) and a lobe-selection uniform `uc` (N,).

    Returns (wi, weight (N, 3), pdf (N,), delta (N,) bool); weight is zero for invalid samples.
    """
    n = len(wo)
    wi, weight, pdf, delta = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool)
    for family, idx in _groups(s.family):
        if idx is None:
            return family.sample(s, wo, u, uc)
        wi[idx], weight[idx], pdf[idx], delta[idx] = family.sample(s.take(idx), wo[idx], u[idx], uc[idx])
    return wi, weight, pdf, delta
