"""One LSNIF object (Sec. 3): its voxels, its sparse grid encoder and its MLP, in the object's local space.

`network_inputs` turns rays into the network's input (the walk's boundary points, normalised to the voxel
box); `forward` maps the concatenated per-point features to the raw outputs
[occlusion, distance, normal (3), albedo (3), material logits (K)]; `predict` applies the output
activations of Sec. 5.3 and answers hits in the rays' own units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.encoding import VoxelGridEncoding
from workers.render.voxels import BoundaryPoints, VoxelGrid, boundary_points

OUTPUTS_BEFORE_MATERIALS = 8
INFERENCE_CHUNK = 1 << 16
STORAGE_DTYPE = torch.float16


@dataclass
class EncodedRays:
    """Network inputs for N rays: points in [0, 1]^3 (N, H, 3), which slots hold a point, and the walk."""

    points: np.ndarray
    valid: np.ndarray
    walk: BoundaryPoints

    def take(self, rows: np.ndarray) -> EncodedRays:
        return EncodedRays(self.points[rows], self.valid[rows], self.walk.take(rows))


@dataclass
class Prediction:
    """What the object answers for N rays; meaningful where `hit`."""

    hit: np.ndarray  # (N,) bool: occlusion probability >= 0.5 and the ray reached the voxels
    t: np.ndarray  # (N,) distance along the given direction (inf on a miss)
    normal: np.ndarray  # (N, 3) unit shading normal, local space
    albedo: np.ndarray  # (N, 3)
    material: np.ndarray  # (N,) index into the object's material list


def network_inputs(grid: VoxelGrid, origins, directions, max_points: int) -> EncodedRays:
    """The walk over each ray's whole segment in the box, as network inputs. Training labels hits on
    whole segments, so shorter queries (shadow rays) compare the predicted distance with their end."""
    walk = boundary_points(grid, origins, directions, max_points)
    valid = np.arange(max_points)[None, :] < walk.count[:, None]
    points = np.where(valid[..., None], grid.normalize(walk.points), 0.0)
    return EncodedRays(points.astype(np.float32), valid, walk)


class LsnifObject(nn.Module):
    """Voxels + encoder + MLP of one object; `grid` fixes the local box the rays are walked through."""

    def __init__(self, grid: VoxelGrid, n_materials: int, config: LsnifConfig) -> None:
        super().__init__()
        self.grid = grid
        self.max_points = config.max_points
        self.n_materials = n_materials
        self.encoding = VoxelGridEncoding(grid.occupied, config.grid)
        self.mlp = config.mlp.build(
            config.max_points * self.encoding.n_output_dims, OUTPUTS_BEFORE_MATERIALS + n_materials
        )

    def forward(self, points: Tensor, valid: Tensor) -> Tensor:
        """Raw outputs [N, 8 + K] for points [N, H, 3] in [0, 1]^3 with slot mask [N, H].

        Only filled slots are encoded (a ray fills ~4 of 18 on average, so encoding the zero-filled
        rest cost most of a step); empty slots feed zeros to the MLP, as in the paper."""
        features = points.new_zeros(*valid.shape, self.encoding.n_output_dims)
        features[valid] = self.encoding(points[valid])
        return self.mlp(features.flatten(1))

    @torch.no_grad()
    def predict(self, origins: np.ndarray, directions: np.ndarray) -> Prediction:
        """Closest hits of rays given in local space (directions of any non-zero length)."""
        encoded = network_inputs(self.grid, origins, directions, self.max_points)
        walk = encoded.walk
        n = len(origins)
        raw = np.zeros((n, OUTPUTS_BEFORE_MATERIALS + self.n_materials), np.float32)
        rows = np.flatnonzero(walk.count > 0)  # no occupied voxel on the segment: a certain miss
        device = next(self.parameters()).device
        for start in range(0, len(rows), INFERENCE_CHUNK):
            chunk = rows[start : start + INFERENCE_CHUNK]
            points = torch.from_numpy(encoded.points[chunk]).to(device)
            valid = torch.from_numpy(encoded.valid[chunk]).to(device)
            raw[chunk] = self(points, valid).float().cpu().numpy()
        raw = raw.astype(np.float64)
        hit = (walk.count > 0) & (raw[:, 0] >= 0.0)  # sigmoid >= 0.5
        local = 1.0 / (1.0 + np.exp(-np.clip(raw[:, 1], -60, 60)))
        t = np.where(hit, walk.t_near + local * (walk.t_far - walk.t_near), np.inf)
        normal = raw[:, 2:5]
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.where(length > 1e-12, normal / np.maximum(length, 1e-12), [0.0, 0.0, 1.0])
        albedo = 1.0 / (1.0 + np.exp(-np.clip(raw[:, 5:8], -60, 60)))
        material = raw[:, OUTPUTS_BEFORE_MATERIALS:].argmax(1)
        return Prediction(hit, t, normal, albedo, material)

    def size_bytes(self) -> int:
        """Bytes the artifact stores for this object: packed voxel bits, the box, and the feature table
        and MLP in float16."""
        weights = sum(p.numel() for p in self.parameters()) * torch.finfo(STORAGE_DTYPE).bits // 8
        box = self.grid.lo.nbytes + self.grid.size.nbytes
        return int(np.ceil(self.grid.occupied.size / 8)) + box + weights
