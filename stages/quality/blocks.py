"""Grids held block-major, the way the occupancy store chunks them, so a frame is decoded straight
into the memory the scores read (no copy into an ``(X, Y, Z)`` array: at 0.05 m that copy cost
as much as decoding).

A :class:`BlockedGrid` of logical shape ``(X, Y, Z)`` holds ``blocks`` of shape
``(nbx, nby, bx, by, Z)``: ``blocks[p, q]`` is the column block of voxels
``[p*bx, (p+1)*bx) x [q*by, (q+1)*by) x [0, Z)``, C-ordered, so one stored chunk is one
contiguous block. Blocks at the high x / y edges may reach past ``X`` / ``Y``; that padding is
never read. A dense ``(X, Y, Z)`` array is the grid of one block (:meth:`BlockedGrid.dense`, no
copy), so every kernel has one form.

A visibility mask is held as bits packed along z in the same blocks (:class:`BitGrid`, the
layout of the stored ``observed_bits``): one eighth of the bytes to decode and to read.

Kernels read the grid as one flat array: voxel ``(i, j, k)`` is element ``ox[i] + oy[j] + k``
with the per-axis offset tables of :meth:`BlockedGrid.offsets` (two lookups and an add where a
kernel would divide by the block edges per voxel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class BlockedGrid:
    """A grid of logical shape ``(X, Y, Z)`` held as ``(nbx, nby, bx, by, Z)`` blocks (module
    docstring). ``blocks`` is C-contiguous; its dtype is the grid's."""

    blocks: np.ndarray
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        b, (X, Y, Z) = self.blocks, self.shape
        if b.ndim != 5 or not b.flags.c_contiguous:
            raise ValueError(f"blocks must be a C-contiguous (nbx, nby, bx, by, Z) array, got shape {b.shape}")
        nbx, nby, bx, by, bz = b.shape
        # the blocks cover the grid, and no block lies wholly outside it
        if bz != Z or not (X == 0 or nbx * bx >= X > (nbx - 1) * bx) or not (Y == 0 or nby * by >= Y > (nby - 1) * by):
            raise ValueError(f"blocks of shape {b.shape} do not tile a grid of shape {self.shape}")

    @classmethod
    def dense(cls, grid: np.ndarray) -> BlockedGrid:
        """A dense ``(X, Y, Z)`` array as the grid of one block (a view when it is C-contiguous)."""
        a = np.ascontiguousarray(grid)
        if a.ndim != 3:
            raise ValueError(f"grid must be 3D (x, y, z), got shape {a.shape}")
        return cls(a.reshape(1, 1, *a.shape), tuple(int(n) for n in a.shape))

    @classmethod
    def empty(cls, shape: tuple[int, int, int], block: tuple[int, int], dtype) -> BlockedGrid:
        """An all-zero grid of ``shape`` in ``block = (bx, by)`` column blocks (a buffer to decode
        frames into, frame after frame)."""
        X, Y, Z = shape
        bx, by = block
        return cls(np.zeros((-(-X // bx), -(-Y // by), bx, by, Z), dtype), (int(X), int(Y), int(Z)))

    @property
    def block(self) -> tuple[int, int]:
        """``(bx, by)``: the x and y edges of a block, in voxels."""
        return int(self.blocks.shape[2]), int(self.blocks.shape[3])

    @property
    def dtype(self) -> np.dtype:
        return self.blocks.dtype

    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ox, oy)``, int64 ``(X,)`` and ``(Y,)``: voxel ``(i, j, k)`` is element
        ``ox[i] + oy[j] + k`` of :attr:`flat`. With ``blocks`` of shape ``(nbx, nby, bx, by, Z)``
        the C-order offset of ``blocks[i // bx, j // by, i % bx, j % by, k]`` splits into
        ``((i // bx) * nby * bx * by + (i % bx) * by) * Z`` and ``((j // by) * bx * by + j % by) * Z``."""
        _, nby, bx, by, Z = self.blocks.shape
        i = np.arange(self.shape[0], dtype=np.int64)
        j = np.arange(self.shape[1], dtype=np.int64)
        return ((i // bx) * nby * bx * by + (i % bx) * by) * Z, ((j // by) * bx * by + j % by) * Z

    @property
    def flat(self) -> np.ndarray:
        """The blocks as one flat array (a view)."""
        return self.blocks.reshape(-1)

    def words(self) -> np.ndarray:
        """The whole 8-byte words of :attr:`flat` as uint64 (a view; kernels skip free voxels
        eight at a time through it)."""
        return words_of(self.flat.view(np.uint8))

    def like(self, other: BlockedGrid | np.ndarray, name: str) -> BlockedGrid:
        """``other`` (a grid of this shape) in this grid's blocks: itself when it already is,
        else a copy re-blocked."""
        o = as_blocked(other, name)
        if o.shape != self.shape:
            raise ValueError(f"{name} has shape {o.shape}, its semantic grid has {self.shape}")
        if o.blocks.shape == self.blocks.shape:
            return o
        return BlockedGrid.from_dense(o.to_dense(), self.block)

    def to_dense(self) -> np.ndarray:
        """The ``(X, Y, Z)`` array (a copy, except for a one-block grid)."""
        nbx, nby, bx, by, Z = self.blocks.shape
        X, Y, _ = self.shape
        if nbx == nby == 1 and (bx, by) == (X, Y):
            return self.blocks[0, 0]
        return self.blocks.transpose(0, 2, 1, 3, 4).reshape(nbx * bx, nby * by, Z)[:X, :Y]

    @classmethod
    def from_dense(cls, grid: np.ndarray, block: tuple[int, int]) -> BlockedGrid:
        """A dense ``(X, Y, Z)`` array copied into ``block = (bx, by)`` column blocks (zero padding)."""
        a = np.asarray(grid)
        if a.ndim != 3:
            raise ValueError(f"grid must be 3D (x, y, z), got shape {a.shape}")
        out = cls.empty(a.shape, block, a.dtype)
        nbx, nby, bx, by, _ = out.blocks.shape
        # block (p, q) is the dense grid's [p*bx, (p+1)*bx) x [q*by, (q+1)*by) columns
        for p in range(nbx):
            for q in range(nby):
                part = a[p * bx:(p + 1) * bx, q * by:(q + 1) * by]
                out.blocks[p, q, :part.shape[0], :part.shape[1]] = part
        return out


@dataclass(frozen=True)
class BitGrid:
    """A 0/1 grid of logical shape ``(X, Y, Z)`` held as bits packed along z in column blocks:
    ``blocks`` of shape ``(nbx, nby, bx, by, ceil(Z / 8))`` uint8, voxel ``(i, j, k)`` being bit
    ``k % 8`` (little bit order) of byte ``k // 8`` of its column in block ``(i // bx, j // by)``.
    That is the layout of ``observed_bits``'s stored chunks, decoded one per block; a mask is
    one eighth of the bytes of its uint8 grid (module docstring for the blocks)."""

    blocks: np.ndarray
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        b, (X, Y, Z) = self.blocks, self.shape
        if b.ndim != 5 or b.dtype != np.uint8 or not b.flags.c_contiguous:
            raise ValueError(f"bit blocks must be a C-contiguous uint8 (nbx, nby, bx, by, ceil(Z/8)) array, "
                             f"got {b.dtype} {b.shape}")
        nbx, nby, bx, by, bz = b.shape
        if bz != -(-Z // 8) or not (X == 0 or nbx * bx >= X > (nbx - 1) * bx) or not (
                Y == 0 or nby * by >= Y > (nby - 1) * by):
            raise ValueError(f"bit blocks of shape {b.shape} do not tile a grid of shape {self.shape}")

    @classmethod
    def pack(cls, grid: BlockedGrid) -> BitGrid:
        """A grid's nonzero voxels as bits, in the same blocks."""
        return cls(np.packbits(grid.blocks != 0, axis=-1, bitorder="little"), grid.shape)

    @property
    def block(self) -> tuple[int, int]:
        return int(self.blocks.shape[2]), int(self.blocks.shape[3])

    @property
    def flat(self) -> np.ndarray:
        return self.blocks.reshape(-1)

    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ox, oy)``: the byte holding voxel ``(i, j, k)`` is ``flat[ox[i] + oy[j] + k // 8]``
        (:meth:`BlockedGrid.offsets` with a column of ``ceil(Z / 8)`` bytes)."""
        _, nby, bx, by, zb = self.blocks.shape
        i = np.arange(self.shape[0], dtype=np.int64)
        j = np.arange(self.shape[1], dtype=np.int64)
        return ((i // bx) * nby * bx * by + (i % bx) * by) * zb, ((j // by) * bx * by + j % by) * zb

    def unpacked(self) -> BlockedGrid:
        """The uint8 0/1 grid in the same blocks (a copy)."""
        Z = self.shape[2]
        return BlockedGrid(np.ascontiguousarray(np.unpackbits(self.blocks, axis=-1, count=Z, bitorder="little")),
                           self.shape)


@numba.njit(cache=True, nogil=True, inline="always")
def first_bit(bits, base, lo, hi):  # pragma: no cover - numba
    """The lowest ``k`` in ``[lo, hi]`` whose bit is set in the packed column starting at byte
    ``base`` of ``bits`` (bit ``k % 8`` of byte ``base + k // 8``); ``hi + 1`` when none. Zero
    bytes are skipped eight voxels at a time."""
    k = lo
    while k <= hi:
        b = bits[base + (k >> 3)] >> (k & 7)
        if b == 0:
            k = (k | 7) + 1  # the next byte
            continue
        while (b & 1) == 0:  # the lowest set bit of the rest of this byte
            b >>= 1
            k += 1
        return k if k <= hi else hi + 1
    return hi + 1


@numba.njit(cache=True, nogil=True, inline="always")
def last_bit(bits, base, lo, hi):  # pragma: no cover - numba
    """The highest ``k`` in ``[lo, hi]`` whose bit is set (see :func:`first_bit`); ``lo - 1``
    when none."""
    k = hi
    while k >= lo:
        b = bits[base + (k >> 3)] & ((2 << (k & 7)) - 1)  # bits 0 .. k % 8 of k's byte
        if b == 0:
            k = (k & ~7) - 1  # the previous byte's last bit
            continue
        p = 7
        while (b >> p) == 0:  # the highest set bit of the byte
            p -= 1
        k = (k & ~7) + p
        return k if k >= lo else lo - 1
    return lo - 1


def words_of(flat: np.ndarray) -> np.ndarray:
    """The whole 8-byte words of a flat uint8 array, as uint64 (a view)."""
    return flat[: flat.size // 8 * 8].view(np.uint64)


def as_blocked(grid, name: str) -> BlockedGrid:
    """``grid`` as a :class:`BlockedGrid` (a dense array becomes one block, no copy)."""
    if isinstance(grid, BlockedGrid):
        return grid
    a = np.asarray(grid)
    if a.ndim != 3:
        raise ValueError(f"{name} must be 3D (x, y, z), got shape {a.shape}")
    return BlockedGrid.dense(a)


def uint8_grid(semantic, name: str) -> BlockedGrid:
    """A semantic grid (dense array or :class:`BlockedGrid`) as uint8 blocks
    (ValueError naming ids outside 0..255)."""
    grid = as_blocked(semantic, name)
    if grid.dtype == np.bool_:  # occupied / free: class 1 / 0
        grid = grid.view(np.uint8)
    if grid.dtype != np.uint8:
        b = grid.blocks
        if not np.issubdtype(b.dtype, np.integer):
            raise ValueError(f"{name} must hold integer class ids, got {b.dtype}")
        if b.size and (b.min() < 0 or b.max() > 255):
            raise ValueError(f"{name}: semantic ids must fit uint8 (0..255)")
        grid = BlockedGrid(b.astype(np.uint8), grid.shape)
    return grid


@numba.njit(cache=True, nogil=True, inline="always")
def first_nonzero(flat, words, start, end):  # pragma: no cover - numba
    """Index of the first nonzero byte of ``flat[start:end]`` (``end`` when none); ``words`` is
    ``flat``'s whole 8-byte words (:meth:`BlockedGrid.words`), which skip free voxels 8 at a time."""
    p = start
    # bytes up to a word boundary
    while p < end and (p & 7) != 0:
        if flat[p] != 0:
            return p
        p += 1
    # whole words, four at a time, then one at a time
    while p + 32 <= end and (words[p >> 3] | words[(p >> 3) + 1] | words[(p >> 3) + 2] | words[(p >> 3) + 3]) == 0:
        p += 32
    while p + 8 <= end and words[p >> 3] == 0:
        p += 8
    # the first nonzero word, or the tail
    while p < end:
        if flat[p] != 0:
            return p
        p += 1
    return end


@numba.njit(cache=True, nogil=True, inline="always")
def last_nonzero(flat, words, start, end):  # pragma: no cover - numba
    """Index of the last nonzero byte of ``flat[start:end]`` (``start - 1`` when none); see
    :func:`first_nonzero`."""
    p = end
    # bytes down to a word boundary
    while p > start and (p & 7) != 0:
        p -= 1
        if flat[p] != 0:
            return p
    # whole words, four at a time, then one at a time
    while p - 32 >= start and (words[(p >> 3) - 1] | words[(p >> 3) - 2] | words[(p >> 3) - 3]
                               | words[(p >> 3) - 4]) == 0:
        p -= 32
    while p - 8 >= start and words[(p >> 3) - 1] == 0:
        p -= 8
    # the last nonzero word, or the head
    while p > start:
        p -= 1
        if flat[p] != 0:
            return p
    return start - 1
