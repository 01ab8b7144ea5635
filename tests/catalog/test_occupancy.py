import numpy as np
import pytest

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

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
    with pytest.raises(ValueError, match="tile shape"):
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


@pytest.mark.parametrize("memory", [False, True])
def test_write_tile_round_trips_through_zarr_with_edge_chunks_and_empty_chunks(tmp_path, memory):
    from carlaocc.catalog.store import Store

    store = Store(f"memory://occ-tiles-{memory}") if memory else Store(str(tmp_path / "root"))
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(4.0, 2.5, 1.0), voxel_size=0.1)  # 40x25x10
    occ = OccupancyStore(store)
    occ.create("s", grid, frame_count=2, chunk_edge=16)  # chunks 16 x 16: edge chunks in x and y
    rng = np.random.default_rng(0)
    sem = (rng.random(grid.shape) < 0.2).astype(np.uint8) * rng.integers(1, 30, grid.shape, dtype=np.uint8)
    sem[:16, :16] = 0  # one empty chunk
    inst = sem.astype(np.uint32) * 100_003
    flow = rng.normal(size=(*grid.shape, 3)).astype(np.float16) * (sem > 0)[..., None]
    for x0 in (0, 16, 32):  # three tiles, the last one 8 wide (the array's end)
        occ.write_tile("s", grid, 1, "semantic", sem[x0:x0 + 16], x0)
        occ.write_tile("s", grid, 1, "instance", inst[x0:x0 + 16], x0)
        occ.write_tile("s", grid, 1, "flow", flow[x0:x0 + 16], x0)
    back = occ.read_frame("s", grid, 1, ("semantic", "instance", "flow"))
    np.testing.assert_array_equal(back["semantic"], sem)
    np.testing.assert_array_equal(back["instance"], inst)
    np.testing.assert_array_equal(back["flow"], flow)
    assert occ.open("s", grid, "flow").shape == (2, *grid.shape, 3)
    assert not occ.read_frame("s", grid, 0)["semantic"].any()
    # the empty chunk is not stored; re-writing a chunk as empty removes it
    fp = occ.frame_fingerprint(occ.array_path("s", grid, "semantic"), 1)
    root = f"occupancy.zarr/{occ.array_path('s', grid, 'semantic')}/c/1"
    assert not store.fs.exists(store.path(f"{root}/0/0/0")) and store.fs.exists(store.path(f"{root}/1/0/0"))
    sem2 = sem.copy()
    sem2[16:32] = 0
    occ.write_tile("s", grid, 1, "semantic", sem2[16:32], 16)
    assert not store.fs.exists(store.path(f"{root}/1/0/0"))
    np.testing.assert_array_equal(occ.read_frame("s", grid, 1, ("semantic",))["semantic"], sem2)
    assert occ.frame_fingerprint(occ.array_path("s", grid, "semantic"), 1) != fp
    # candidate chunks: the ones holding data are written, a candidate that holds none is removed
    inst2 = inst.copy()
    inst2[32:, 16:] = 0
    candidates = np.array([[True, True]])  # the last tile: 1 x 2 chunks of 16
    occ.write_tile("s", grid, 1, "instance", inst2[32:], 32, candidates)
    np.testing.assert_array_equal(occ.read_frame("s", grid, 1, ("instance",))["instance"], inst2)
    iroot = f"occupancy.zarr/{occ.array_path('s', grid, 'instance')}/c/1"
    assert not store.fs.exists(store.path(f"{iroot}/2/1/0")) and store.fs.exists(store.path(f"{iroot}/2/0/0"))
    assert occ.chunk_edges("s", grid, "instance") == (16, 16)
    # tiles must cover whole chunks
    with pytest.raises(ValueError, match="whole chunks"):
        occ.write_tile("s", grid, 1, "semantic", sem[8:24], 8)
    with pytest.raises(ValueError, match="whole chunks"):
        occ.write_tile("s", grid, 1, "semantic", sem[0:10], 0)


from hypothesis import given, settings
from hypothesis import strategies as st


@settings(max_examples=80, deadline=None)
@given(nx=st.integers(1, 9), ny=st.integers(1, 9), nz=st.integers(1, 11), cx=st.integers(1, 4), cy=st.integers(1, 4),
       dtype=st.sampled_from(["uint8", "uint32", "float16"]), trailing=st.sampled_from([(), (3,)]),
       seed=st.integers(0, 2**32 - 1))
def test_chunk_flags_match_a_numpy_reference(nx, ny, nz, cx, cy, dtype, trailing, seed):
    from carlaocc.catalog.occupancy import chunk_flags

    rng = np.random.default_rng(seed)
    data = np.zeros((nx, ny, nz, *trailing), dtype=dtype)
    n = rng.integers(0, 4)
    for _ in range(n):  # a few isolated nonzero values anywhere (unaligned runs included)
        idx = tuple(rng.integers(0, s) for s in data.shape)
        data[idx] = 1
    got = chunk_flags(data, cx, cy)
    want = np.zeros_like(got)
    for a in range(got.shape[0]):
        for b in range(got.shape[1]):
            want[a, b] = data[a * cx:(a + 1) * cx, b * cy:(b + 1) * cy].any()
    np.testing.assert_array_equal(got, want)
    # candidates: only those chunks are read (a chunk left out is reported empty)
    candidates = rng.random(got.shape) < 0.5
    np.testing.assert_array_equal(chunk_flags(data, cx, cy, candidates), want & candidates)
    with pytest.raises(ValueError, match="one flag per chunk"):
        chunk_flags(data, cx, cy, np.ones((got.shape[0] + 1, got.shape[1]), bool))


def test_write_chunks_from_a_block_function(tmp_path):
    from carlaocc.catalog.store import Store

    store = Store(str(tmp_path / "root"))
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(4.0, 2.5, 1.0), voxel_size=0.1)  # 40x25x10
    occ = OccupancyStore(store)
    occ.create("s", grid, frame_count=1, chunk_edge=16)
    rng = np.random.default_rng(2)
    want = (rng.random(grid.shape) < 0.3).astype(np.uint8)
    want[16:32, 16:] = 0  # an empty (edge) chunk: the block function says None
    asked = []

    def block(ci, cj):
        asked.append((ci, cj))
        b = want[ci * 16:(ci + 1) * 16, cj * 16:(cj + 1) * 16]  # edge chunks smaller: padded on write
        return np.ascontiguousarray(b) if b.any() else None

    occ.write_chunks("s", grid, 0, "mask_camera", 0, 40, block)
    assert sorted(asked) == [(i, j) for i in range(3) for j in range(2)]
    np.testing.assert_array_equal(occ.read_frame("s", grid, 0, ("mask_camera",))["mask_camera"], want)
    root = f"occupancy.zarr/{occ.array_path('s', grid, 'mask_camera')}/c/0"
    assert not store.fs.exists(store.path(f"{root}/1/1/0")) and store.fs.exists(store.path(f"{root}/2/1/0"))
