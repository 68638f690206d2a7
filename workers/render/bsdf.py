"""BSDFs as plugins registered by name, evaluated and sampled over batches mixing them (wavefront style).

A BSDF family (`diffuse`, `conductor`, ...; the built-in ones are in `workers.render.bsdfs`) subclasses
`BSDF` and registers with `@register_material("name")`; the scene's materials map to families by their
`type`. Batches carry a family code per row: `eval_bsdf` and `sample_bsdf` hand each family the rows of
its own kind, so a new family needs no dispatch table. A family written in NumPy implements `eval` and
`sample` over a batch of its own rows; the built-in ones are compiled kernels (`workers.render.kernels`)
that read and write their rows of the whole batch in place (`eval_rows`, `sample_rows`).

Conventions, in the local shading frame (z = normal): `wo` points to the camera (or previous vertex),
`wi` towards the light; both unit. `eval` returns f(wo, wi) * |cos(wi)| and the solid-angle pdf of
`sample` producing wi; delta lobes are never returned by `eval` (so a surface with only delta lobes evaluates
to 0, and the path tracer samples lights there with no shadow ray). `sample` returns wi, the weight
f |cos| / pdf (what a path's throughput is multiplied by), the pdf (0 for delta lobes), a delta flag and
eta, the relative index of refraction of the sampled event: the far side's index over wo's side's for a
transmission, 1 for a reflection (and for an invalid sample). Transmission carries the 1/eta^2 radiance
scaling; the path tracer's Russian roulette undoes it with eta (`wavefront._roulette`). Families that
only reflect leave eta at the 1 the batch starts with. Two-sided families see wo.z > 0 (the caller flips the
frame); the others (dielectrics) see both sides and use the sign of wo.z to know which side they are on.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from workers.render.jit import njit
from workers.scene.format.spec import ColorOrTexture


@dataclass
class SurfaceBatch:
    """Material parameters at N shading points."""

    family: np.ndarray  # (N,) int8 code of a registered BSDF family (`bsdf_code`)
    base: np.ndarray  # (N, 3): diffuse reflectance, or conductor specular colour
    alpha: np.ndarray  # (N,) GGX alpha; 0 means perfectly smooth
    ior: np.ndarray  # (N,) interior over exterior
    extra: np.ndarray | None = None  # (N, K) family-specific parameters (`MaterialParameters.extra`)
    # the rows grouped by family, computed by the first `eval_bsdf` or `sample_bsdf` (`_groups`)
    by_family: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def take(self, idx: np.ndarray) -> SurfaceBatch:
        extra = None if self.extra is None else self.extra[idx]
        return SurfaceBatch(self.family[idx], self.base[idx], self.alpha[idx], self.ior[idx], extra)

    def assign(self, idx: np.ndarray, rows: SurfaceBatch) -> None:
        """Write `rows` (a batch of len(idx) rows, e.g. after textures changed them) back at `idx`."""
        self.base[idx], self.alpha[idx], self.ior[idx] = rows.base, rows.alpha, rows.ior
        if self.extra is not None and rows.extra is not None:
            self.extra[idx, : rows.extra.shape[1]] = rows.extra

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

    @abstractmethod
    def parameters(self, material: Any) -> MaterialParameters:
        """The rows' parameters of a scene material (`workers.scene.format.spec`) of this family."""

    @abstractmethod
    def eval(self, s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f |cos theta_i| and the pdf of sampling wi, per row (local frames)."""

    @abstractmethod
    def sample(self, s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
        """wi, weight f |cos| / pdf, pdf, whether the sampled lobe is a delta, and the sampled event's
        relative IOR eta (1 for a reflection), per row."""

    def eval_rows(self, s: SurfaceBatch, wo, wi, rows: np.ndarray, out: tuple[np.ndarray, ...]) -> None:
        """`eval` of the batch's `rows` written there into `out` (f_cos, pdf). By default a gather, `eval`
        and a scatter; the compiled families read and write their rows in place."""
        every = len(rows) == len(wo)
        results = self.eval(s, wo, wi) if every else self.eval(s.take(rows), wo[rows], wi[rows])
        for array, result in zip(out, results, strict=True):
            array[slice(None) if every else rows] = result

    def sample_rows(self, s: SurfaceBatch, wo, u, uc, rows: np.ndarray, out: tuple[np.ndarray, ...]) -> None:
        """`sample` of the batch's `rows` into `out` (wi, weight, pdf, delta, eta), as `eval_rows`."""
        every = len(rows) == len(wo)
        results = (
            self.sample(s, wo, u, uc) if every else self.sample(s.take(rows), wo[rows], u[rows], uc[rows])
        )
        for array, result in zip(out, results, strict=True):
            array[slice(None) if every else rows] = result

    def textures(self, material: Any) -> dict[str, Any]:
        """The material's textured parameters by slot name (`workers.scene.format.spec` textures); none by
        default. The slots `normal` and `emission` are the renderer's (`workers.render.materials`)."""
        return {}

    def apply_textures(self, material: Any, s: SurfaceBatch, lookups: dict[str, np.ndarray]) -> None:  # noqa: B027
        """Overwrite the rows `s` of `material` with its textures' values `lookups` (slot -> (N, 3) RGB);
        a family without textures never receives any."""


class CompiledBSDF(BSDF):
    """A family whose rows are evaluated and sampled by compiled kernels (`eval_kernel`, `sample_kernel`)
    reading and writing their rows of the whole batch; `eval` and `sample` run them on every row. A
    subclass that redefines `eval` or `sample` (in NumPy, say) is dispatched through its own method."""

    @abstractmethod
    def eval_kernel(self, s: SurfaceBatch, wo, wi, rows: np.ndarray, out: tuple[np.ndarray, ...]) -> None: ...

    @abstractmethod
    def sample_kernel(
        self, s: SurfaceBatch, wo, u, uc, rows: np.ndarray, out: tuple[np.ndarray, ...]
    ) -> None: ...

    def eval(self, s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(wo)
        out = np.zeros((n, 3)), np.zeros(n)
        self.eval_kernel(s, wo, wi, np.arange(n), out)
        return out

    def sample(self, s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
        n = len(wo)
        out = _sample_outputs(n)
        self.sample_kernel(s, wo, u, uc, np.arange(n), out)
        return out

    def eval_rows(self, s: SurfaceBatch, wo, wi, rows: np.ndarray, out: tuple[np.ndarray, ...]) -> None:
        if type(self).eval is CompiledBSDF.eval:
            self.eval_kernel(s, wo, wi, rows, out)
        else:
            super().eval_rows(s, wo, wi, rows, out)

    def sample_rows(self, s: SurfaceBatch, wo, u, uc, rows: np.ndarray, out: tuple[np.ndarray, ...]) -> None:
        if type(self).sample is CompiledBSDF.sample:
            self.sample_kernel(s, wo, u, uc, rows, out)
        else:
            super().sample_rows(s, wo, u, uc, rows, out)


class _Registry:
    """Families by name and by code; per-code flags as arrays so batches look them up with one gather."""

    def __init__(self) -> None:
        self.families: list[BSDF] = []
        self.codes: dict[str, int] = {}
        self.two_sided = np.zeros(0, bool)

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


def _groups(s: SurfaceBatch):
    """(family, rows) for each family present, rows ascending; grouped once per batch (its eval and its
    sample share the grouping)."""
    if s.by_family is None:
        s.by_family = _rows_by_family(np.asarray(s.family, np.int8), len(_registry.families))
    rows, starts = s.by_family
    for code in range(len(starts) - 1):
        if starts[code + 1] > starts[code]:
            yield _registry.families[code], rows[starts[code] : starts[code + 1]]


@njit(cache=True, nogil=True, fastmath=False)
def _rows_by_family(family, count):
    """The rows grouped by family code, ascending within each (a counting sort: one pass, where a
    `np.unique` and a `flatnonzero` per family took several), and where each code's rows start
    (count + 1 entries)."""
    starts = np.zeros(count + 1, np.int64)
    for code in family:
        starts[code + 1] += 1
    for code in range(count):
        starts[code + 1] += starts[code]
    rows, fill = np.empty(len(family), np.int64), starts[:-1].copy()
    for i in range(len(family)):
        rows[fill[family[i]]] = i
        fill[family[i]] += 1
    return rows, starts


def eval_bsdf(s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f(wo, wi) |cos wi| (N, 3) and the pdf of sampling wi (N,)."""
    n = len(wo)
    out = np.zeros((n, 3)), np.zeros(n)
    for family, rows in _groups(s):
        family.eval_rows(s, wo, wi, rows, out)
    return out


def _sample_outputs(n: int) -> tuple[np.ndarray, ...]:
    """Zeroed (wi, weight, pdf, delta) and eta = 1 (a reflection's) for `n` samples."""
    return np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool), np.ones(n)


def sample_bsdf(s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
    """Sample wi given wo, two uniforms `u` (N, 2) and a lobe-selection uniform `uc` (N,).

    Returns (wi, weight (N, 3), pdf (N,), delta (N,) bool, eta (N,)); weight is zero for invalid samples.
    """
    n = len(wo)
    out = _sample_outputs(n)
    for family, rows in _groups(s):
        family.sample_rows(s, wo, u, uc, rows, out)
    return out
