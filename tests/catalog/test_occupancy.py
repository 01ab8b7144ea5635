import numpy as np
import pytest

from catalog.occupancy import OccupancyStore
from schemas.grid import GridSpec
from schemas.taxonomy import TAXONOMY_VERSION

GRID = GridSpec(region_min=(-2.0, -1.0, -0.5), region_max=(2.0, 1.0, 0.5), voxel_size=0.25)


def test_create_write_read_with_attributes(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, frame_count=3, chunk_edge=16)
    sem = np.zeros(GRID.shape, np.uint8)
    sem[1, 2, 3] = 14
    inst = np.zeros(GRID.shape, np.uint32)
    inst[1, 2, 3] = 70000  # beyond uint16: no 11-bit cap
    out = occ.write_frame("seq", GRID, 1, {"semantic": sem, "instance": inst})
    assert set(out) == {"occupancy.zarr/seq/0.25/semantic[1]", "occupancy.zarr/seq/0.25/instance[1]"}
    back = occ.read_frame("seq", GRID, 1)
    np.testing.assert_array_equal(back["semantic"], sem)
    np.testing.assert_array_equal(back["instance"], inst)
    assert not occ.read_frame("seq", GRID, 0)["semantic"].any()
    arr = occ.open("seq", GRID, "semantic")
    assert arr.shape == (3, *GRID.shape)
    assert arr.chunks[0] == 1 and arr.chunks[3] == GRID.shape[2]
    attrs = dict(arr.attrs)
    assert attrs["voxel_size"] == 0.25
    assert attrs["origin"] == [-2.0, -1.0, -0.5]
    assert attrs["frame"] == "lidar"
    assert attrs["taxonomy_version"] == TAXONOMY_VERSION
    assert attrs["grid_spec"]["voxel_size"] == 0.25
    assert attrs["dims"] == ["frame", "x", "y", "z"]


def test_create_keeps_identical_arrays_and_their_data(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 2, 16)
    sem = np.full(GRID.shape, 3, np.uint8)
    occ.write_frame("seq", GRID, 0, {"semantic": sem})
    occ.create("seq", GRID, 2, 16)  # the same spec again: kept
    assert occ.read_frame("seq", GRID, 0, ("semantic",))["semantic"].min() == 3
    occ.create("seq", GRID, 4, 16)  # another frame count: replaced
    assert occ.open("seq", GRID, "semantic").shape[0] == 4


def test_write_frame_rejects_wrong_shape(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 1, 16)
    with pytest.raises(ValueError, match="frame shape"):
        occ.write_frame("seq", GRID, 0, {"semantic": np.zeros((2, 2, 2), np.uint8)})


def test_exists(store):
    occ = OccupancyStore(store)
    assert not occ.exists("seq", GRID, "semantic")
    occ.create("seq", GRID, 2, 16)
    assert occ.exists("seq", GRID, "semantic", 1) and not occ.exists("seq", GRID, "semantic", 2)


def test_frame_fingerprint_tracks_stored_chunks(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 2, 8)
    sem = np.zeros(GRID.shape, np.uint8)
    sem[:, :, 0] = 1
    out = occ.write_frame("seq", GRID, 0, {"semantic": sem})
    (key, fp), = out.items()
    path = occ.array_path("seq", GRID, "semantic")
    assert occ.frame_fingerprint(path, 0) == fp
    assert occ.frame_fingerprint(path, 1) != fp  # another frame, no chunks
    # rewriting the same data keeps it; other data or a lost chunk changes it
    assert occ.write_frame("seq", GRID, 0, {"semantic": sem})[key] == fp
    sem[0, 0, 0] = 2
    fp2 = occ.write_frame("seq", GRID, 0, {"semantic": sem})[key]
    assert fp2 != fp
    chunk = sorted(store.fs.find(store.path(f"occupancy.zarr/{path}/c/0")))[-1]
    store.fs.rm(chunk)
    assert occ.frame_fingerprint(path, 0) not in (fp, fp2)
    assert occ.frame_fingerprint("nope/0.25/semantic", 0) is None
