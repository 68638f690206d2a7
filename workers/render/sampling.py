"""Warps from the unit square and orthonormal frames, vectorised over batches (float64)."""

from __future__ import annotations

import numpy as np

INV_PI = 1.0 / np.pi


def safe_sqrt(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(x, 0.0))


def normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-30)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def coordinate_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents (s, t) completing unit normals n to a right-handed frame (Duff et al. 2017, branchless)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return s, t


def to_local(v: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.stack([dot(v, s), dot(v, t), dot(v, n)], axis=1)


def to_world(v: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n


def square_to_cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """Malley's method on the polar disk map (cheaper than the concentric map for i.i.d. samples)."""
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), safe_sqrt(1.0 - u[:, 0])], axis=1)


def square_to_uniform_sphere(u: np.ndarray) -> np.ndarray:
    z = 1.0 - 2.0 * u[:, 0]
    r = safe_sqrt(1.0 - z * z)
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def square_to_uniform_triangle(u: np.ndarray) -> np.ndarray:
    """Barycentrics (b1, b2) uniform over a triangle (Heitz's low-distortion split)."""
    u0, u1 = u[:, 0], u[:, 1]
    lower = u1 > u0
    b0 = np.where(lower, u0 / 2, u0 - u1 / 2)
    b1 = np.where(lower, u1 - u0 / 2, u1 / 2)
    return np.stack([b0, b1], axis=1)


def power_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """Veach's power heuristic (beta 2); safe when both pdfs are zero or infinite."""
    a2 = np.square(np.minimum(pdf_a, 1e150))
    b2 = np.square(np.minimum(pdf_b, 1e150))
    denom = a2 + b2
    return np.where(denom > 0, a2 / np.where(denom > 0, denom, 1.0), 0.0)


def select_where(mask: np.ndarray) -> np.ndarray | slice:
    """Indices where `mask` holds, or a full slice when it holds everywhere (a view, not a copy)."""
    return slice(None) if mask.all() else np.flatnonzero(mask)


def selection_size(sel: np.ndarray | slice, n: int) -> int:
    return n if isinstance(sel, slice) else len(sel)


def max3(rgb: np.ndarray) -> np.ndarray:
    """Largest of the three channels; much faster than `.max(axis=1)` on (N, 3) arrays."""
    return np.maximum(np.maximum(rgb[:, 0], rgb[:, 1]), rgb[:, 2])


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.212671, 0.715160, 0.072169])
