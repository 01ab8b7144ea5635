"""The quality kernels on block-major grids (what the store decodes) agree with the dense grids
and the brute-force references, for any block edges, edge padding and column height."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.quality import (column_ranges, continuity_and_ranges, isolated_mask_reference,
                                     spatial_continuity_counts)
from carlaocc.stages.quality.blocks import BlockedGrid, first_bit, last_bit
from carlaocc.stages.quality.statistics import block_pairs, instance_class_pairs


def blocked(dense: np.ndarray, bx: int, by: int, pad: int = 0) -> BlockedGrid:
    """``dense`` cut into (bx, by) column blocks, the padding beyond the grid filled with ``pad``
    (the kernels must never read it)."""
    grid = BlockedGrid.from_dense(dense, (bx, by))
    X, Y, _ = dense.shape
    nbx, nby = grid.blocks.shape[:2]
    grid.blocks[nbx - 1, :, X - (nbx - 1) * bx:] = pad
    grid.blocks[:, nby - 1, :, Y - (nby - 1) * by:] = pad
    return grid


def reference_ranges(sem: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Z = sem.shape[2]
    nz = sem != 0
    lo = np.where(nz.any(axis=2), nz.argmax(axis=2), Z)
    hi = np.where(nz.any(axis=2), Z - 1 - nz[:, :, ::-1].argmax(axis=2), -1)
    return lo, hi


@st.composite
def grids(draw, labels=(0, 0, 0, 1, 2, 3)):
    shape = (draw(st.integers(1, 9)), draw(st.integers(1, 9)), draw(st.integers(1, 41)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    density = draw(st.sampled_from([0.0, 0.05, 0.5, 1.0]))
    sem = (rng.choice(np.asarray(labels[3:], np.uint8), size=shape) * (rng.random(shape) < density)).astype(np.uint8)
    return sem, draw(st.integers(1, 5)), draw(st.integers(1, 5)), draw(st.sampled_from([0, 1, 255]))


@settings(max_examples=120, deadline=None)
@given(grids())
def test_continuity_and_ranges_agree_with_the_references_for_any_blocks(case):
    sem, bx, by, pad = case
    counts, (lo, hi) = continuity_and_ranges(blocked(sem, bx, by, pad))
    ref = isolated_mask_reference(sem)
    for c in range(1, 4):
        assert counts.occupied[c] == int((sem == c).sum())
        assert counts.isolated[c] == int((ref & (sem == c)).sum())
    rlo, rhi = reference_ranges(sem)
    np.testing.assert_array_equal(lo, rlo)
    np.testing.assert_array_equal(hi, rhi)
    # the dense form (one block) and the ranges-only pass agree too
    dense = spatial_continuity_counts(sem)
    assert (dense.occupied == counts.occupied).all() and (dense.isolated == counts.isolated).all()
    for a, b in zip(column_ranges(blocked(sem, bx, by, pad)), (rlo, rhi)):
        np.testing.assert_array_equal(a, b)


def test_ranges_out_buffers_are_filled_and_checked():
    sem = np.zeros((3, 4, 20), np.uint8)
    sem[1, 2, 5:9] = 3
    lo, hi = np.full((3, 4), 7, np.int32), np.full((3, 4), 7, np.int32)  # stale values
    _, (a, b) = continuity_and_ranges(blocked(sem, 2, 3), out=(lo, hi))
    assert a is lo and b is hi
    np.testing.assert_array_equal(lo, reference_ranges(sem)[0])
    np.testing.assert_array_equal(hi, reference_ranges(sem)[1])
    with pytest.raises(ValueError, match="int32 arrays of shape"):
        continuity_and_ranges(sem, out=(np.zeros((3, 4), np.int64), hi))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 300))
def test_block_pairs_agree_with_the_whole_frame(seed, n_ids):
    rng = np.random.default_rng(seed)
    shape = tuple(rng.integers(1, 8, 2)) + (int(rng.integers(1, 700)),)
    sem = (rng.integers(1, 30, shape) * (rng.random(shape) < 0.4)).astype(np.uint8)
    # things carry ids, and a few free voxels too (against the contract: neither counts them)
    inst = np.where((sem > 20) | (rng.random(shape) < 0.05), rng.integers(1, n_ids + 1, shape), 0).astype(np.uint32)
    lo, hi = reference_ranges(sem)
    np.testing.assert_array_equal(block_pairs(sem, inst, lo.astype(np.int32), hi.astype(np.int32)),
                                  instance_class_pairs(sem, inst))


def test_blocked_grid_layout():
    dense = np.arange(5 * 3 * 2, dtype=np.uint8).reshape(5, 3, 2)
    g = blocked(dense, 2, 2, pad=77)
    assert g.blocks.shape == (3, 2, 2, 2, 2) and g.block == (2, 2)
    np.testing.assert_array_equal(g.to_dense(), dense)
    ox, oy = g.offsets()
    for i in range(5):
        for j in range(3):
            np.testing.assert_array_equal(g.flat[ox[i] + oy[j]:ox[i] + oy[j] + 2], dense[i, j])
    one = BlockedGrid.dense(dense)
    assert one.blocks.base is dense or np.shares_memory(one.blocks, dense)
    np.testing.assert_array_equal(g.like(dense, "x").to_dense(), dense)
    np.testing.assert_array_equal(one.like(g, "x").to_dense(), dense)
    with pytest.raises(ValueError, match="do not tile"):
        BlockedGrid(np.zeros((3, 2, 2, 2, 2), np.uint8), (7, 3, 2))
    with pytest.raises(ValueError, match="has shape"):
        g.like(np.zeros((5, 3, 3), np.uint8), "mask_t")


# -- visibility as bits packed along z (BitGrid: observed_bits as the store decodes it) ---------
@settings(max_examples=80, deadline=None)
@given(grids())
def test_bit_grid_packs_a_mask_in_its_blocks(case):
    from carlaocc.stages.quality.blocks import BitGrid

    sem, bx, by, pad = case
    grid = blocked(sem, bx, by, pad)
    bits = BitGrid.pack(grid)
    X, Y, Z = sem.shape
    assert bits.blocks.shape == (*grid.blocks.shape[:4], -(-Z // 8)) and bits.block == (bx, by)
    # every voxel's bit is where the offset tables say, and is set exactly where the mask is nonzero
    ox, oy = bits.offsets()
    i, j, k = np.meshgrid(np.arange(X), np.arange(Y), np.arange(Z), indexing="ij")
    got = (bits.flat[ox[i] + oy[j] + k // 8] >> (k % 8)) & 1
    np.testing.assert_array_equal(got, sem != 0)
    np.testing.assert_array_equal(bits.unpacked().to_dense(), (sem != 0).astype(np.uint8))


@numba.njit(cache=False)
def _first_and_last_bit(bits, base, lo, hi):  # compiled once for every example below
    return first_bit(bits, base, lo, hi), last_bit(bits, base, lo, hi)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 70), st.data())
def test_first_and_last_bit_agree_with_a_scan(seed, Z, data):
    rng = np.random.default_rng(seed)
    col = rng.random(Z) < data.draw(st.sampled_from([0.0, 0.02, 0.3, 1.0]))
    base = data.draw(st.integers(0, 3))
    packed = np.concatenate([rng.integers(0, 256, base, dtype=np.uint8), np.packbits(col, bitorder="little"),
                             rng.integers(0, 256, 2, dtype=np.uint8)])  # neighbours' bytes must not count
    lo = data.draw(st.integers(0, Z - 1))
    hi = data.draw(st.integers(lo - 1, Z - 1))
    set_ = np.flatnonzero(col[lo:hi + 1]) + lo if hi >= lo else np.zeros(0, int)
    first, last = _first_and_last_bit(packed, base, lo, hi)
    assert first == (set_[0] if len(set_) else hi + 1)
    assert last == (set_[-1] if len(set_) else lo - 1)


def test_bit_grid_is_checked():
    from carlaocc.stages.quality.blocks import BitGrid

    with pytest.raises(ValueError, match="do not tile"):
        BitGrid(np.zeros((1, 1, 4, 4, 2), np.uint8), (4, 4, 17))
    with pytest.raises(ValueError, match="uint8"):
        BitGrid(np.zeros((1, 1, 4, 4, 2), np.uint16), (4, 4, 9))
