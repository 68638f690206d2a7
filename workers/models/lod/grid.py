"""The sparse multi-level voxel grid of a prefiltered asset (Weier et al. 2023, Sec. 4.1).

LoD 0 is the finest level: voxels that the asset's triangles overlap (exact triangle-box test, shared
with `lsnif` in `workers.render.voxels`); each coarser level halves the resolution and is the union of its
children. Only occupied voxels are stored: per level their sorted linear keys and their visibility
thresholds (Sec. 4.4). The grid is a cube in world space, so voxels are cubes at every level and the voxel
centres of all levels form the geometric sequence the appearance network's hash grid is built on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.render.voxels import VoxelGrid, coarsen, padded_bounds, voxelize

DEFAULT_THRESHOLD = 0.5


@dataclass
class LodGrid:
    lo: np.ndarray  # (3,) corner of the cube
    extent: float  # side of the cube
    resolutions: list[int]  # voxels per side, LoD 0 (finest) first
    keys: list[np.ndarray]  # per level: sorted int64 keys (x * R + y) * R + z of occupied voxels
    thresholds: list[np.ndarray] = field(default_factory=list)  # per level, per key: visible iff p >= t
    _dense: dict[int, VoxelGrid] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.thresholds:
            self.thresholds = [np.full(len(k), DEFAULT_THRESHOLD, np.float32) for k in self.keys]

    @classmethod
    def build(cls, triangles: np.ndarray, resolutions: list[int]) -> LodGrid:
        """Voxelise world-space triangles (T, 3, 3) at resolutions[0] and coarsen down the list."""
        finest = resolutions[0]
        bounds = padded_bounds(triangles.reshape(-1, 3), finest)
        centre, extent = bounds.mean(0), float((bounds[1] - bounds[0]).max())
        lo = centre - extent / 2
        faces = np.arange(3 * len(triangles)).reshape(-1, 3)
        occupied = voxelize(triangles.reshape(-1, 3), faces, finest, np.stack([lo, lo + extent])).occupied
        keys = []
        for r in resolutions:
            while occupied.shape[0] > r:
                occupied = coarsen(occupied)
            keys.append(np.flatnonzero(occupied.reshape(-1)).astype(np.int64))
        return cls(lo, extent, list(resolutions), keys)

    @property
    def levels(self) -> int:
        return len(self.resolutions)

    @property
    def shifts(self) -> np.ndarray:
        """Per level, log2 of LoD 0's resolution over the level's: a LoD-0 cell >> shift is its ancestor."""
        return np.round(np.log2(self.resolutions[0] / np.asarray(self.resolutions))).astype(np.int64)

    def voxel_size(self, level: int) -> float:
        return self.extent / self.resolutions[level]

    def cells(self, level: int, keys: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) voxel indices of `keys` (default: every occupied voxel of the level)."""
        keys = self.keys[level] if keys is None else keys
        return np.stack(np.unravel_index(keys, (self.resolutions[level],) * 3), 1).astype(np.int64)

    def key(self, level: int, cells: np.ndarray) -> np.ndarray:
        r = self.resolutions[level]
        return (cells[:, 0] * r + cells[:, 1]) * r + cells[:, 2]

    def index(self, level: int, cells: np.ndarray) -> np.ndarray:
        """Row of each occupied voxel `cells` in the level's key and threshold arrays."""
        return np.searchsorted(self.keys[level], self.key(level, cells))

    def threshold(self, level: int, cells: np.ndarray) -> np.ndarray:
        return self.thresholds[level][self.index(level, cells)]

    def boxes(self, level: int, cells: np.ndarray, grow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) corners of voxels `cells`, each side grown by `grow` x the voxel size."""
        size = self.voxel_size(level)
        lo = self.lo + cells * size
        return lo - grow * size, lo + size + grow * size

    def normalize(self, points: np.ndarray) -> np.ndarray:
        """Points in cube coordinates [0, 1]^3: the networks' position inputs."""
        return (points - self.lo) / self.extent

    def centres(self, level: int | np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Voxel centres in cube coordinates (they never coincide across levels); `level` may be per cell."""
        resolution = np.asarray(self.resolutions)[np.asarray(level)]
        return (cells + 0.5) / np.expand_dims(resolution, -1)

    def level_grid(self, level: int) -> VoxelGrid:
        """The level as a dense occupancy grid for ray walks (built once per level on first use)."""
        if level not in self._dense:
            r = self.resolutions[level]
            occupied = np.zeros(r**3, bool)
            occupied[self.keys[level]] = True
            size = np.full(3, self.voxel_size(level))
            self._dense[level] = VoxelGrid(self.lo.astype(np.float64), size, occupied.reshape(r, r, r))
        return self._dense[level]

    def occupancy(self, level: int) -> float:
        """Fraction of the level's voxels that are occupied (1 - sparsity)."""
        return len(self.keys[level]) / self.resolutions[level] ** 3

    def storage_bytes(self) -> int:
        """As stored in the artifact: a uint32 key and a float16 threshold per occupied voxel and level."""
        return sum(6 * len(k) for k in self.keys)

    def arrays(self) -> dict[str, np.ndarray]:
        """The grid as named arrays for safetensors."""
        out = {"grid.lo": self.lo, "grid.extent": np.array([self.extent]), "grid.resolutions": np.array(
            self.resolutions, np.int64)}  # fmt: skip
        for level, (keys, thresholds) in enumerate(zip(self.keys, self.thresholds, strict=True)):
            out[f"grid.keys.{level}"] = keys.astype(np.uint32)
            out[f"grid.thresholds.{level}"] = thresholds.astype(np.float16)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> LodGrid:
        resolutions = [int(r) for r in arrays["grid.resolutions"]]
        levels = range(len(resolutions))
        return cls(
            arrays["grid.lo"].astype(np.float64),
            float(arrays["grid.extent"][0]),
            resolutions,
            [arrays[f"grid.keys.{level}"].astype(np.int64) for level in levels],
            [arrays[f"grid.thresholds.{level}"].astype(np.float32) for level in levels],
        )
