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

from carlaocc.stages.quality.blocks import BlockedGrid, first_nonzero, last_nonzero, uint8_grid

N_CLASSES = 256  # counts are kept per uint8 value; the taxonomy uses 0..29


@numba.njit(cache=True, nogil=True, parallel=True)
def _count_and_ranges_kernel(flat, words, ox, oy, Z, lo, hi, n_slabs):  # pragma: no cover - numba
    """Per-class occupied and isolated counts of a grid read through its offset tables (voxel
    (i, j, k) is ``flat[ox[i] + oy[j] + k]``, :class:`~.blocks.BlockedGrid`), and into ``lo``,
    ``hi`` (``(X, Y)`` int32) per column the lowest and highest k with a nonzero label (``Z`` and
    -1 when none)."""
    X, Y = ox.size, oy.size
    occ = np.zeros((n_slabs, N_CLASSES), dtype=np.int64)
    iso = np.zeros((n_slabs, N_CLASSES), dtype=np.int64)
    # one slab of x rows per parallel iteration; per-slab counters avoid write races
    for slab in numba.prange(n_slabs):
        for i in range(slab * X // n_slabs, (slab + 1) * X // n_slabs):
            for j in range(Y):
                _column(flat, words, ox, oy, Z, lo, hi, occ, iso, slab, i, j)
    # reduce the per-slab counters
    return occ.sum(axis=0), iso.sum(axis=0)


@numba.njit(cache=True, nogil=True, inline="always")
def _column(flat, words, ox, oy, Z, lo, hi, occ, iso, slab, i, j):  # pragma: no cover - numba
    """:func:`_count_and_ranges_kernel` for the column (i, j), counting into row ``slab``."""
    X, Y = ox.size, oy.size
    s = ox[i] + oy[j]
    # the column's occupied extent, free voxels skipped eight at a time
    first = first_nonzero(flat, words, s, s + Z) - s
    if first == Z:
        lo[i, j] = Z
        hi[i, j] = -1
        return
    last = last_nonzero(flat, words, s + first, s + Z) - s
    lo[i, j] = first
    hi[i, j] = last
    # the four face-neighbour columns (-1 where outside the grid)
    sl = ox[i - 1] + oy[j] if i > 0 else -1
    sr = ox[i + 1] + oy[j] if i + 1 < X else -1
    sd = ox[i] + oy[j - 1] if j > 0 else -1
    su = ox[i] + oy[j + 1] if j + 1 < Y else -1
    # runs of one label along z: a voxel of a run of two or more has a z neighbour of its class,
    # so only single-voxel runs can be isolated (checked against the four columns)
    k = first
    while k <= last:
        c = flat[s + k]
        end = k + 1
        while end <= last and flat[s + end] == c:
            end += 1
        if c != 0:
            occ[slab, c] += end - k
            if end - k == 1 and not ((sl >= 0 and flat[sl + k] == c) or (sr >= 0 and flat[sr + k] == c)
                                     or (sd >= 0 and flat[sd + k] == c) or (su >= 0 and flat[su + k] == c)):
                iso[slab, c] += 1
        k = end


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


def spatial_continuity_counts(semantic: np.ndarray | BlockedGrid) -> ContinuityCounts:
    """Per-class occupied and isolated (6-neighbourhood) voxel counts of a 3D semantic grid
    (uint8 class ids, dense ``(X, Y, Z)`` or :class:`~.blocks.BlockedGrid`)."""
    return continuity_and_ranges(semantic)[0]


def continuity_and_ranges(semantic: np.ndarray | BlockedGrid, out: tuple[np.ndarray, np.ndarray] | None = None,
                          ) -> tuple[ContinuityCounts, tuple[np.ndarray, np.ndarray]]:
    """:func:`spatial_continuity_counts` and the grid's per-column occupied z ranges (what
    :func:`carlaocc.stages.quality.temporal.column_ranges` gives) from one pass over a 3D semantic
    grid (dense or :class:`~.blocks.BlockedGrid`, as the store decodes it: no copy): at 0.05 m
    each pass reads 400 MB, free voxels 32 at a time. ``out``: two int32 ``(X, Y)`` arrays to
    fill with the ranges (buffers reused frame after frame)."""
    grid = uint8_grid(semantic, "semantic grid")
    X, Y, Z = grid.shape
    if out is None:
        out = (np.empty((X, Y), np.int32), np.empty((X, Y), np.int32))
    lo, hi = out
    if any(a.shape != (X, Y) or a.dtype != np.int32 or not a.flags.c_contiguous for a in out):
        raise ValueError(f"out must be two C-contiguous int32 arrays of shape {(X, Y)}")
    ox, oy = grid.offsets()
    occ, iso = _count_and_ranges_kernel(grid.flat, grid.words(), ox, oy, Z, lo, hi, max(1, min(X, 64)))
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
