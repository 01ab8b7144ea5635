"""Spatial Continuity Score (paper, section 4.2).

For a semantic grid ``O`` and every class ``c >= 1`` (0 is free), the occupied set is
``V_c = {v | O(v) = c}`` and the isolated set ``I_c = {v in V_c | O(u) != c for all u in N6(v)}``,
with ``N6`` the 6-connected face neighbours (neighbours outside the grid count as "not c").
The score over a set of frames is ``s_sc = 1 - sum |I_c| / sum |V_c|`` summed over frames and
classes; a grid with no occupied voxel has no defined score (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

N_CLASSES = 256  # counts are kept per uint8 value; the taxonomy uses 0..29


@numba.njit(cache=True, nogil=True, parallel=True)
def _count_kernel(sem: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X, Y, Z = sem.shape
    occ = np.zeros((X, N_CLASSES), dtype=np.int64)
    iso = np.zeros((X, N_CLASSES), dtype=np.int64)
    # one x-slab per parallel iteration; per-slab counters avoid write races
    for i in numba.prange(X):
        for j in range(Y):
            for k in range(Z):
                c = sem[i, j, k]
                if c == 0:
                    continue
                occ[i, c] += 1
                # a voxel is connected when any face neighbour carries the same class
                if i > 0 and sem[i - 1, j, k] == c:
                    continue
                if i + 1 < X and sem[i + 1, j, k] == c:
                    continue
                if j > 0 and sem[i, j - 1, k] == c:
                    continue
                if j + 1 < Y and sem[i, j + 1, k] == c:
                    continue
                if k > 0 and sem[i, j, k - 1] == c:
                    continue
                if k + 1 < Z and sem[i, j, k + 1] == c:
                    continue
                iso[i, c] += 1
    # reduce the per-slab counters
    return occ.sum(axis=0), iso.sum(axis=0)


@numba.njit(cache=True, nogil=True, parallel=True)
def _count_and_ranges_kernel(sem: np.ndarray):  # pragma: no cover - numba
    """:func:`_count_kernel` that also records, per (i, j) column, the lowest and highest k with
    a nonzero label (``lo = Z``, ``hi = -1`` when none): one pass where two would read the grid."""
    X, Y, Z = sem.shape
    occ = np.zeros((X, N_CLASSES), dtype=np.int64)
    iso = np.zeros((X, N_CLASSES), dtype=np.int64)
    lo = np.full((X, Y), Z, dtype=np.int32)
    hi = np.full((X, Y), -1, dtype=np.int32)
    for i in numba.prange(X):
        for j in range(Y):
            first, last = Z, -1
            for k in range(Z):
                c = sem[i, j, k]
                if c == 0:
                    continue
                if first == Z:
                    first = k
                last = k
                occ[i, c] += 1
                # a voxel is connected when any face neighbour carries the same class
                if i > 0 and sem[i - 1, j, k] == c:
                    continue
                if i + 1 < X and sem[i + 1, j, k] == c:
                    continue
                if j > 0 and sem[i, j - 1, k] == c:
                    continue
                if j + 1 < Y and sem[i, j + 1, k] == c:
                    continue
                if k > 0 and sem[i, j, k - 1] == c:
                    continue
                if k + 1 < Z and sem[i, j, k + 1] == c:
                    continue
                iso[i, c] += 1
            lo[i, j] = first
            hi[i, j] = last
    return occ.sum(axis=0), iso.sum(axis=0), lo, hi


def pooled_continuity(occupied: int, isolated: int) -> float:
    """``1 - isolated / occupied`` from voxel counts summed over any classes and frames (the one
    definition of the score: a frame's, a sequence's and a dataset's); NaN when ``occupied`` is 0."""
    return float("nan") if occupied == 0 else 1.0 - isolated / occupied


@dataclass(frozen=True)
class ContinuityCounts:
    """Per-class occupied and isolated voxel counts of one or more grids (index = class id)."""

    occupied: np.ndarray  # (256,) int64
    isolated: np.ndarray  # (256,) int64

    @property
    def score(self) -> float:
        """``1 - isolated / occupied`` over classes >= 1; NaN when nothing is occupied."""
        return pooled_continuity(int(self.occupied[1:].sum()), int(self.isolated[1:].sum()))

    def __add__(self, other: ContinuityCounts) -> ContinuityCounts:
        return ContinuityCounts(self.occupied + other.occupied, self.isolated + other.isolated)


def spatial_continuity_counts(semantic: np.ndarray) -> ContinuityCounts:
    """Per-class occupied and isolated (6-neighbourhood) voxel counts of a 3D uint8 semantic grid."""
    sem = np.ascontiguousarray(semantic)
    if sem.ndim != 3:
        raise ValueError(f"semantic grid must be 3D (x, y, z), got shape {sem.shape}")
    if sem.dtype != np.uint8:
        if sem.size and (sem.min() < 0 or sem.max() > 255):
            raise ValueError("semantic ids must fit uint8 (0..255)")
        sem = sem.astype(np.uint8)
    occ, iso = _count_kernel(sem)
    return ContinuityCounts(occ, iso)


def continuity_and_ranges(semantic: np.ndarray) -> tuple[ContinuityCounts, tuple[np.ndarray, np.ndarray]]:
    """:func:`spatial_continuity_counts` and the grid's per-column occupied z ranges (what
    :func:`carlaocc.stages.quality.temporal.column_ranges` gives) from one pass over a 3D uint8
    semantic grid: at 0.05 m each pass reads 400 MB."""
    sem = np.ascontiguousarray(semantic)
    if sem.ndim != 3:
        raise ValueError(f"semantic grid must be 3D (x, y, z), got shape {sem.shape}")
    if sem.dtype != np.uint8:
        raise ValueError(f"semantic grid must be uint8 class ids, got {sem.dtype}")
    occ, iso, lo, hi = _count_and_ranges_kernel(sem)
    return ContinuityCounts(occ, iso), (lo, hi)


def sequence_continuity(per_frame: list[ContinuityCounts]) -> ContinuityCounts:
    """Counts summed over frames (the paper's sums over t)."""
    total = ContinuityCounts(np.zeros(N_CLASSES, np.int64), np.zeros(N_CLASSES, np.int64))
    for c in per_frame:
        total = total + c
    return total


def isolated_mask_reference(semantic: np.ndarray) -> np.ndarray:
    """Brute-force numpy reference: boolean mask of isolated occupied voxels (for tests)."""
    sem = np.asarray(semantic)
    padded = np.pad(sem.astype(np.int32), 1, constant_values=-1)
    centre = padded[1:-1, 1:-1, 1:-1]
    has_same = np.zeros(sem.shape, dtype=bool)
    # compare with each of the six face-neighbour shifts
    for axis in range(3):
        for step in (-1, 1):
            sl = [slice(1, -1)] * 3
            sl[axis] = slice(1 + step, padded.shape[axis] - 1 + step)
            has_same |= padded[tuple(sl)] == centre
    return (sem > 0) & ~has_same
