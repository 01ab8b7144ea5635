"""The occupied voxels built tile by tile (stages/voxelize/sparse.py) against the dense
voxelization (``voxelize_scene``): the same voxels and labels for every fill mode and tile width;
the word-skipping extraction against ``np.flatnonzero``; the sparse fill breakdown against the
dense one."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.voxels import SparseVoxels
from carlaocc.stages.voxelize.breakdown import fill_breakdown, sparse_fill_breakdown
from carlaocc.stages.voxelize.compose import voxelize_scene
from carlaocc.stages.voxelize.sparse import nonzero_bytes, occupied_voxels

GRID = GridSpec(region_min=(-2.0, -2.0, -0.5), region_max=(2.8, 2.0, 2.5), voxel_size=0.1)  # 48 x 40 x 30
ROAD, BUILDING, CAR, VEGETATION = 1, 3, 14, 9


def _scene() -> list[SceneMesh]:
    """A road plane, a closed car (thing), a building without its floor (open: winding numbers),
    a tree crown (stuff), overlapping so the elevation order matters."""
    road = trimesh.creation.box(extents=(5.0, 4.5, 0.02))
    road.apply_translation((0.4, 0.0, -0.2))
    car = trimesh.creation.box(extents=(1.6, 0.8, 0.6))
    car.apply_translation((-0.9, 0.3, 0.12))
    house = trimesh.creation.box(extents=(1.4, 1.6, 1.8))
    house.apply_translation((1.3, -0.6, 0.98))  # floor 0.08 m: open to the outside below
    floorless = house.faces[house.face_normals[:, 2] > -0.5]  # drop the floor: an open mesh
    crown = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    crown.apply_translation((0.2, 1.2, 1.6))
    return [SceneMesh(road.vertices, road.faces, ROAD, 0, True, True, name="road"),
            SceneMesh(car.vertices, car.faces, CAR, 1, False, True, name="car"),
            SceneMesh(house.vertices, floorless, BUILDING, 0, True, False, name="house"),
            SceneMesh(crown.vertices, crown.faces, VEGETATION, 0, True, True, name="crown")]


@pytest.mark.parametrize("fill", ["surface", "auto", "solid"])
@pytest.mark.parametrize("tile_x", [1, 7, 64])
def test_occupied_voxels_are_the_dense_voxelization(fill, tile_x):
    meshes = _scene()
    # the same tile width on both sides (compose.py, "Tiles": widths agree up to an ulp of the
    # shift, which a centre exactly on an open mesh's rim can see)
    ds, di = voxelize_scene(meshes, GRID, fill, tile_x=tile_x)
    want = SparseVoxels.from_dense(GRID, ds, di)
    got = occupied_voxels(meshes, GRID, fill, tile_x=tile_x)
    np.testing.assert_array_equal(got.index, want.index)
    np.testing.assert_array_equal(got.semantic, want.semantic)
    np.testing.assert_array_equal(got.instance, want.instance)
    assert got.semantic.dtype == np.uint8 and got.instance.dtype == np.uint32
    assert set(np.unique(got.instance)) == {0, 1} and len(got) > 0
    s, i = got.dense()
    np.testing.assert_array_equal(s, ds)
    np.testing.assert_array_equal(i, di)


def test_no_mesh_in_the_grid_gives_no_voxels():
    far = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    far.apply_translation((50.0, 0.0, 0.0))
    got = occupied_voxels([SceneMesh(far.vertices, far.faces, CAR, 1, False, True)], GRID, "auto")
    assert len(got) == 0 and not got.dense()[0].any()


@pytest.mark.parametrize("fill", ["surface", "auto", "solid"])
def test_sparse_fill_breakdown_is_the_dense_one(fill):
    meshes = _scene()
    voxels = occupied_voxels(meshes, GRID, fill)
    got = sparse_fill_breakdown(meshes, voxels, fill)
    assert got == fill_breakdown(meshes, GRID, fill)
    assert got.total == len(voxels)
    if fill != "surface":
        assert got.filled > 0 and got.from_holes > 0  # the floorless house fills through its hole


@settings(max_examples=60, deadline=None)
@given(n=st.integers(0, 200), start=st.integers(0, 9), density=st.floats(0.0, 1.0), seed=st.integers(0, 2**16),
       base=st.integers(0, 2**33))
def test_nonzero_bytes_is_flatnonzero(n, start, density, seed, base):
    rng = np.random.default_rng(seed)
    buf = np.where(rng.random(n + start) < density, rng.integers(1, 256, n + start), 0).astype(np.uint8)
    values = buf[start:]  # unaligned starts too (then read byte by byte)
    index, out = nonzero_bytes(values, base)
    want = np.flatnonzero(values)
    np.testing.assert_array_equal(index, base + want)
    np.testing.assert_array_equal(out, values[want])
    assert index.dtype == np.int64 and out.dtype == np.uint8
    if base + n < 2**32:
        small, _ = nonzero_bytes(values, base, np.uint32)
        assert small.dtype == np.uint32 and np.array_equal(small, index)
