"""The observed bits (stages/voxelize/observed.py): the union of the traced masks' column bits,
cut into blocks packed along z, equals np.packbits of the unpacked masks' union for any grid
height; what voxelize writes as observed_bits and the quality stage reads."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas.grid import GridSpec
from carlaocc.stages.voxelize import visibility as vis
from carlaocc.stages.voxelize.observed import observed_columns, packed_block, unpack_z


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(3, 140), st.integers(1, 9), st.integers(1, 9))
def test_packed_blocks_of_traced_masks_equal_packbits_of_the_union(seed, nz, bx, by):
    rng = np.random.default_rng(seed)
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(1.3, 1.1, nz * 0.1), voxel_size=0.1)  # 13 x 11 x nz
    X, Y, Z = grid.shape
    vol = vis.pack_occupancy(rng.random(grid.shape) < 0.03, grid)
    # two masks traced from two points, as the LiDAR's and the cameras' are
    masks = []
    for name in ("a", "b"):
        m = vol.new_mask()
        vol.trace(m, rng.random(3) * np.array([1.3, 1.1, Z * 0.1]), rng.normal(size=(300, 3)), 5.0)
        masks.append(m)
    union = vol.or_into(masks[0], np.zeros(grid.shape, np.uint8))
    vol.or_into(masks[1], union)
    observed = observed_columns(*masks, out=np.empty_like(masks[0]))
    want = np.packbits(union, axis=-1, bitorder="little")
    for i0 in range(0, X, bx):
        for j0 in range(0, Y, by):
            b = packed_block(observed, grid.shape, i0, j0, min(bx, X - i0), min(by, Y - j0))
            part = want[i0:i0 + bx, j0:j0 + by]
            if b is None:  # an empty block is not stored
                assert not part.any()
            else:
                np.testing.assert_array_equal(b, part)
                np.testing.assert_array_equal(unpack_z(b, Z), union[i0:i0 + bx, j0:j0 + by])


def test_bits_past_the_grid_height_are_cleared_and_blocks_checked():
    shape = (2, 3, 13)  # one column word, two bytes of which 13 bits count
    words = np.full(2 * 3, np.uint64(2**64 - 1), np.uint64)
    b = packed_block(words, shape, 0, 0, 2, 3)
    assert b.shape == (2, 3, 2) and (b[..., 0] == 255).all() and (b[..., 1] == 0b11111).all()
    assert packed_block(np.zeros(6, np.uint64), shape, 0, 0, 2, 3) is None
    with pytest.raises(ValueError, match="outside"):
        packed_block(words, shape, 1, 0, 2, 3)
    with pytest.raises(ValueError, match="do not fit"):
        packed_block(words[:5], shape, 0, 0, 1, 1)
    with pytest.raises(ValueError, match="one length"):
        observed_columns(words, words[:5])
