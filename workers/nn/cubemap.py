"""Cube maps and lat-long environment maps: directions, resampling between them, texel solid angles.

Lat-long convention (y up): u = atan2(x, -z) / 2pi wrapped to [0, 1), v = acos(y) / pi; row 0 is +y and
texel (i, j) has its centre at ((j + 0.5) / W, (i + 0.5) / H).
Cube maps are [6, S, S, C] with faces +x, -x, +y, -y, +z, -z and the OpenGL face orientation; face
coordinates (s, t) in [0, 1]^2 run along columns and rows.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.nn import functional as F

# For each face: direction = major * axis + sc * s_axis + tc * t_axis, with sc, tc in [-1, 1].
FACE_FRAMES = torch.tensor(
    [
        [[1, 0, 0], [0, 0, -1], [0, -1, 0]],
        [[-1, 0, 0], [0, 0, 1], [0, -1, 0]],
        [[0, 1, 0], [1, 0, 0], [0, 0, 1]],
        [[0, -1, 0], [1, 0, 0], [0, 0, -1]],
        [[0, 0, 1], [1, 0, 0], [0, -1, 0]],
        [[0, 0, -1], [-1, 0, 0], [0, -1, 0]],
    ],
    dtype=torch.float64,
)


def _texel_centres(size: int, like: Tensor) -> Tensor:
    return (torch.arange(size, dtype=like.dtype, device=like.device) + 0.5) / size


def face_uv_to_direction(face: Tensor, s: Tensor, t: Tensor) -> Tensor:
    """Unit directions [..., 3] of face coordinates (s, t) in [0, 1] on faces `face` (int64)."""
    frames = FACE_FRAMES.to(device=s.device, dtype=s.dtype)[face]
    d = (
        frames[..., 0, :]
        + (2 * s - 1)[..., None] * frames[..., 1, :]
        + (2 * t - 1)[..., None] * frames[..., 2, :]
    )
    return F.normalize(d, dim=-1)


def direction_to_face_uv(direction: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Face (int64) and face coordinates (s, t) in [0, 1] of directions [..., 3] (need not be unit)."""
    axis = direction.abs().argmax(dim=-1)
    major = direction.gather(-1, axis[..., None]).squeeze(-1)
    face = 2 * axis + (major < 0).long()
    frames = FACE_FRAMES.to(device=direction.device, dtype=direction.dtype)[face]
    scale = major.abs().clamp(min=1e-30)
    s = ((direction * frames[..., 1, :]).sum(-1) / scale + 1) / 2
    t = ((direction * frames[..., 2, :]).sum(-1) / scale + 1) / 2
    return face, s.clamp(0.0, 1.0), t.clamp(0.0, 1.0)


def cubemap_directions(
    size: int, dtype: torch.dtype = torch.float32, device: torch.device | None = None
) -> Tensor:
    """Unit directions [6, S, S, 3] of the texel centres."""
    centres = _texel_centres(size, torch.empty(0, dtype=dtype, device=device))
    t, s = torch.meshgrid(centres, centres, indexing="ij")
    face = torch.arange(6, device=device)[:, None, None].expand(6, size, size)
    return face_uv_to_direction(face, s.expand(6, size, size), t.expand(6, size, size))


def latlong_to_direction(u: Tensor, v: Tensor) -> Tensor:
    theta, phi = math.pi * v, 2 * math.pi * u
    return torch.stack(
        (torch.sin(theta) * torch.sin(phi), torch.cos(theta), -torch.sin(theta) * torch.cos(phi)), dim=-1
    )


def direction_to_latlong(direction: Tensor) -> tuple[Tensor, Tensor]:
    """(u, v) in [0, 1) x [0, 1] of directions [..., 3] (normalised here; acos argument clamped)."""
    d = F.normalize(direction, dim=-1, eps=1e-30)
    u = torch.remainder(torch.atan2(d[..., 0], -d[..., 2]) / (2 * math.pi), 1.0)
    v = torch.acos(d[..., 1].clamp(-1.0, 1.0)) / math.pi
    return u, v


def _bilinear(image: Tensor, u: Tensor, v: Tensor, wrap_u: bool) -> Tensor:
    """Sample image [H, W, C] at (u, v) in [0, 1]^2 with texel-centre convention; u wraps or clamps."""
    height, width = image.shape[:2]
    x, y = u * width - 0.5, (v * height - 0.5).clamp(0, height - 1)
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0, y0 = x0.long(), y0.long()
    if wrap_u:
        x0, x1 = x0 % width, (x0 + 1) % width
    else:
        x0, x1 = x0.clamp(0, width - 1), (x0 + 1).clamp(0, width - 1)
    y1 = (y0 + 1).clamp(max=height - 1)
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _subtexel_offsets(supersample: int, like: Tensor) -> Tensor:
    return (torch.arange(supersample, dtype=like.dtype, device=like.device) + 0.5) / supersample - 0.5


def latlong_to_cubemap(
    latlong: Tensor, size: int, supersample: int = 4, rotation: Tensor | None = None
) -> Tensor:
    """Resample a lat-long map [H, W, C] to a cube map [6, S, S, C], averaging supersample^2 bilinear
    taps per texel so that small bright sources are not missed when S is much coarser than W / 4.
    `rotation` [3, 3] (local -> world, as the path tracer's environment) turns the map before it is
    resampled: the cube's world direction d reads the map at d @ rotation."""
    offsets = _subtexel_offsets(supersample, latlong)
    centres = _texel_centres(size, latlong)
    t = (centres[:, None] + offsets[None, :] / size).reshape(-1)
    t_grid, s_grid = torch.meshgrid(t, t, indexing="ij")
    n = size * supersample
    face = torch.arange(6, device=latlong.device)[:, None, None].expand(6, n, n)
    directions = face_uv_to_direction(face, s_grid.expand(6, n, n), t_grid.expand(6, n, n))
    if rotation is not None:
        directions = directions @ rotation.to(directions)
    u, v = direction_to_latlong(directions)
    taps = _bilinear(latlong, u, v, wrap_u=True)
    return taps.view(6, size, supersample, size, supersample, -1).mean(dim=(2, 4))


def cubemap_to_latlong(cube: Tensor, height: int, width: int) -> Tensor:
    """Resample a cube map [6, S, S, C] to lat-long [H, W, C], bilinear within each face (edges clamped)."""
    v, u = torch.meshgrid(_texel_centres(height, cube), _texel_centres(width, cube), indexing="ij")
    face, s, t = direction_to_face_uv(latlong_to_direction(u, v))
    size = cube.shape[1]
    flat = cube.reshape(6 * size, size, -1)
    # Sample the stacked faces as one tall image, keeping rows inside the chosen face.
    rows = (t * size - 0.5).clamp(0, size - 1)
    stacked_v = (face * size + rows + 0.5) / (6 * size)
    return _bilinear(flat, s, stacked_v, wrap_u=False)


def cubemap_solid_angles(size: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """Exact solid angle [6, S, S] of each texel; they sum to 4 pi."""
    edges = torch.linspace(-1.0, 1.0, size + 1, dtype=torch.float64)
    a, b = torch.meshgrid(edges, edges, indexing="ij")
    corner = torch.atan2(a * b, torch.sqrt(a * a + b * b + 1))
    texel = corner[1:, 1:] - corner[:-1, 1:] - corner[1:, :-1] + corner[:-1, :-1]
    return texel.expand(6, size, size).to(dtype)


def latlong_solid_angles(height: int, width: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """Solid angle [H, W] of each lat-long texel: (2 pi / W)(cos theta_top - cos theta_bottom)."""
    cos_edges = torch.cos(torch.linspace(0.0, math.pi, height + 1, dtype=torch.float64))
    rows = (cos_edges[:-1] - cos_edges[1:]) * (2 * math.pi / width)
    return rows[:, None].expand(height, width).to(dtype)


def direction_to_texel(direction: Tensor, size: int) -> Tensor:
    """Flat index (face * S + row) * S + col [...] of the texel each direction [..., 3] passes through
    (nearest texel: the lookup under which a cube map's Haar coefficients are the lighting's)."""
    face, s, t = direction_to_face_uv(direction)
    col = (s * size).long().clamp(0, size - 1)
    row = (t * size).long().clamp(0, size - 1)
    return (face * size + row) * size + col
