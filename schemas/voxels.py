"""A voxel grid's occupied voxels and their labels, held sparsely: what ``carlaocc voxelize``
computes and writes (memory proportional to the occupied voxels, not to the grid).

Voxel ``(i, j, k)`` of ``grid.shape`` ``(X, Y, Z)`` has the linear index ``(i * Y + j) * Z + k``
(numpy's C order: ``np.ravel_multi_index``); its box is ``origin + [i, i+1) * voxel_size`` and
so on (metres, the grid's frame). ``index`` holds the occupied voxels' linear indices ascending,
``semantic`` / ``instance`` their labels at the same positions (a semantic id > 0; instance 0
for stuff). Free voxels are those not listed: the dense arrays are zero there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.grid import GridSpec

__all__ = ["SparseVoxels"]


@dataclass(frozen=True)
class SparseVoxels:
    """The occupied voxels of ``grid`` (see the module docstring)."""

    grid: GridSpec
    index: np.ndarray  # (N,) integer (uint32 or int64), ascending, unique: linear C-order voxel indices
    semantic: np.ndarray  # (N,) uint8, > 0
    instance: np.ndarray  # (N,) uint32, 0 = stuff

    def __post_init__(self) -> None:
        n = len(self.index)
        if self.index.ndim != 1 or self.semantic.shape != (n,) or self.instance.shape != (n,):
            raise ValueError(f"index, semantic and instance must be 1-D of one length, got {self.index.shape}, "
                             f"{self.semantic.shape}, {self.instance.shape}")

    def __len__(self) -> int:
        return len(self.index)

    @classmethod
    def from_dense(cls, grid: GridSpec, semantic: np.ndarray, instance: np.ndarray) -> SparseVoxels:
        """The occupied voxels (semantic > 0) of dense ``grid.shape`` arrays."""
        if semantic.shape != tuple(grid.shape) or instance.shape != tuple(grid.shape):
            raise ValueError(f"arrays of shape {semantic.shape} / {instance.shape} on a grid of {grid.shape}")
        index = np.flatnonzero(semantic.reshape(-1))
        return cls(grid, index, semantic.reshape(-1)[index].astype(np.uint8, copy=False),
                   instance.reshape(-1)[index].astype(np.uint32, copy=False))

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """``(semantic uint8, instance uint32)`` of ``grid.shape``, zero where free."""
        shape = tuple(int(s) for s in self.grid.shape)
        semantic = np.zeros(shape, dtype=np.uint8)
        instance = np.zeros(shape, dtype=np.uint32)
        semantic.reshape(-1)[self.index] = self.semantic
        instance.reshape(-1)[self.index] = self.instance
        return semantic, instance

    def ijk(self) -> np.ndarray:
        """``(N, 3)`` int64 voxel indices of the occupied voxels."""
        return np.stack(np.unravel_index(self.index, tuple(self.grid.shape)), axis=1).astype(np.int64, copy=False)
