import numpy as np
import pytest

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.zarrstore import chunk_flags
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

GRID = GridSpec(region_min=(-2.0, -1.0, -0.5), region_max=(2.0, 1.0, 0.5), voxel_size=0.25)


def test_attributes_describe_the_grid(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, frame_count=3, chunk_edge=16, extra_attrs={"lidar_to_ego": [[1.0]]})
    arr = occ.open("seq", GRID, "semantic")
    assert arr.shape == (3, *GRID.shape)
    assert arr.chunks == (1, *GRID.shape[:2], GRID.shape[2])  # chunk edges clipped to the grid, z whole
    attrs = occ.attrs("seq", GRID)  # semantic's by default
    assert list(attrs) == [*GRID.attrs(), "dims", "sequence_id", "taxonomy_version", "lidar_to_ego", "description"]
    assert attrs["voxel_size"] == 0.25
    assert attrs["origin"] == [-2.0, -1.0, -0.5]
    assert attrs["frame"] == "lidar"
    assert attrs["taxonomy_version"] == TAXONOMY_VERSION
    assert attrs["grid_spec"]["voxel_size"] == 0.25
    assert attrs["dims"] == ["frame", "x", "y", "z"]
    assert occ.attrs("seq", GRID, "flow")["dims"] == ["frame", "x", "y", "z", "component"]
    assert occ.stored_grid("seq", 0.25) == GRID
    assert occ.stored_grid("seq", 0.5) is None and occ.stored_grid("nope", 0.25) is None


def test_observed_bits_hold_z_packed_and_read_back_with_plain_zarr(store):
    """observed_bits: (frame, x, y, ceil(Z / 8)) uint8, chunked as the other arrays along x and
    y; what is written reads back through zarr-python and through read_blocks; created again
    identical, it is kept."""
    import zarr

    from carlaocc.catalog.zarrio import zarr_store

    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(3.0, 2.0, 1.3), voxel_size=0.1)  # 30 x 20 x 13
    occ = OccupancyStore(store)
    occ.create("seq", grid, frame_count=2, chunk_edge=16)
    arr = occ.open("seq", grid, "observed_bits")
    assert arr.shape == (2, 30, 20, 2) and arr.chunks == (1, 16, 16, 2) and arr.dtype == np.uint8
    assert occ.attrs("seq", grid, "observed_bits")["dims"] == ["frame", "x", "y", "z_bytes"]
    assert arr.compressors[0].level == 3 and occ.open("seq", grid, "semantic").compressors[0].level == 1
    rng = np.random.default_rng(1)
    mask = rng.random(grid.shape) < 0.3
    bits = np.packbits(mask, axis=-1, bitorder="little")
    occ.write_frame("seq", grid, 1, {"observed_bits": bits})
    plain = zarr.open_group(store=zarr_store(store, "occupancy.zarr"), mode="r")["seq/0.1/observed_bits"][1]
    np.testing.assert_array_equal(plain, bits)
    np.testing.assert_array_equal(np.unpackbits(plain, axis=-1, count=13, bitorder="little"), mask)
    from carlaocc.catalog.zarrio import encode_chunk, get_object

    stored = get_object(store, "occupancy.zarr/seq/0.1/observed_bits/c/1/0/0/0")
    assert stored == encode_chunk(bits[:16, :16], np.uint8, 3)  # the level its metadata states
    blocks = occ.read_blocks("seq", grid, 1, "observed_bits")
    assert blocks.shape == occ.block_layout("seq", grid, "observed_bits") == (2, 2, 16, 16, 2)
    np.testing.assert_array_equal(blocks[1, 0, :14], bits[16:30, :16])
    assert not occ.create("seq", grid, frame_count=2, chunk_edge=16)  # identical: kept


def test_read_frame_reads_semantic_and_instance_by_default(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, frame_count=2, chunk_edge=16)
    sem = np.zeros(GRID.shape, np.uint8)
    sem[1, 2, 3] = 14
    inst = np.zeros(GRID.shape, np.uint32)
    inst[1, 2, 3] = 70000  # beyond uint16: no 11-bit cap
    occ.write_frame("seq", GRID, 1, {"semantic": sem, "instance": inst})
    back = occ.read_frame("seq", GRID, 1)
    assert list(back) == ["semantic", "instance"]
    np.testing.assert_array_equal(back["semantic"], sem)
    np.testing.assert_array_equal(back["instance"], inst)


def test_create_drops_the_arrays_left_out(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 2, 16)
    assert occ.create("seq", GRID, 2, 16, names=("semantic", "instance")) is False  # kept, others dropped
    assert occ.exists("seq", GRID, "semantic") and not occ.exists("seq", GRID, "flow")
    assert not occ.exists("seq", GRID, "mask_camera")
    with pytest.raises(ValueError, match="unknown occupancy arrays.*colour"):
        occ.create("seq", GRID, 2, 16, names=("colour",))


def test_write_frame_rejects_wrong_shape(store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 1, 16)
    with pytest.raises(ValueError, match="seq/0.25/semantic: tile shape"):
        occ.write_frame("seq", GRID, 0, {"semantic": np.zeros((2, 2, 2), np.uint8)})


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


def _tile_grid_store(store, chunk_edge):
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(4.0, 2.5, 1.0), voxel_size=0.1)  # 40x25x10
    occ = OccupancyStore(store)
    occ.create("s", grid, frame_count=1, chunk_edge=chunk_edge)
    return occ, grid


@pytest.mark.parametrize("chunk_edge", [16, 7])
def test_chunks_of_boxes_are_the_chunks_the_boxes_reach(store, chunk_edge):
    occ, grid = _tile_grid_store(store, chunk_edge)
    rng = np.random.default_rng(chunk_edge)
    shape = (chunk_edge * 2, *grid.shape[1:])  # an x-tile of two chunks
    for _ in range(20):
        lo = rng.integers(0, shape, size=(5, 3))
        hi = lo + rng.integers(0, 9, size=(5, 3))  # some boxes empty (hi == lo)
        hi = np.minimum(hi, shape)
        things = np.column_stack([np.arange(1, 6), lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2]])
        inside = np.zeros(shape, np.uint8)  # a reference: the boxes painted, then chunk_flags
        for _, i0, i1, j0, j1, k0, k1 in things:
            inside[i0:i1, j0:j1, k0:k1] = 1
        got = occ.chunks_of_boxes("s", grid, "instance", things, shape)
        assert got.dtype == bool
        np.testing.assert_array_equal(got, chunk_flags(inside, chunk_edge, chunk_edge).astype(bool))
    assert not occ.chunks_of_boxes("s", grid, "instance", np.zeros((0, 7), np.int64), shape).any()


@pytest.mark.parametrize("chunk_edge", [16, 7])
def test_chunks_of_indices_are_the_chunks_holding_them(store, chunk_edge):
    occ, grid = _tile_grid_store(store, chunk_edge)
    rng = np.random.default_rng(chunk_edge)
    shape = (grid.shape[0] - chunk_edge, *grid.shape[1:])  # an x-tile ending at the array's end
    for n in (0, 1, 5, 200):
        flat = rng.choice(int(np.prod(shape)), size=n, replace=False)
        dense = np.zeros(int(np.prod(shape)), np.uint8)
        dense[flat] = 1
        got = occ.chunks_of_indices("s", grid, "flow", flat, shape)
        np.testing.assert_array_equal(got, chunk_flags(dense.reshape(shape), chunk_edge, chunk_edge).astype(bool))


def test_chunk_bookkeeping_feeds_write_tile(store):
    occ, grid = _tile_grid_store(store, 16)
    tile = np.zeros((16, *grid.shape[1:]), np.uint32)
    tile[3:5, 18:20, 2:4] = 7
    things = np.array([[7, 3, 5, 18, 20, 2, 4]])
    candidates = occ.chunks_of_boxes("s", grid, "instance", things, tile.shape)
    np.testing.assert_array_equal(candidates, [[False, True]])
    occ.write_tile("s", grid, 0, "instance", tile, 16, candidates)
    np.testing.assert_array_equal(occ.read_tile("s", grid, 0, "instance", 16, 16), tile)


def _stored_chunks(occ, grid, name, frame):
    """{chunk name: stored bytes} of one frame of one array."""
    from carlaocc.catalog.zarrio import get_object

    shape, chunks, _ = occ.layout("s", grid, name)
    tail = "/0" * (len(shape) - 3)
    out = {}
    for ci in range(-(-shape[1] // chunks[1])):
        for cj in range(-(-shape[2] // chunks[2])):
            key = f"occupancy.zarr/s/{grid.key}/{name}/c/{frame}/{ci}/{cj}{tail}"
            payload = get_object(occ.store, key)
            if payload is not None:
                out[f"{ci}/{cj}{tail}"] = payload
    return out


@pytest.mark.parametrize("chunk_edge", [16, 7])
def test_tiles_written_from_boxes_store_the_chunks_of_the_dense_tile(store, chunk_edge):
    # write_boxes against write_tile of the same tile with chunks_of_boxes' candidates: the same
    # chunk files with the same bytes (boxes overlapping, reaching no data, empty, at the edge)
    occ, grid = _tile_grid_store(store, chunk_edge)
    occ.create("s", grid, frame_count=2, chunk_edge=chunk_edge)
    rng = np.random.default_rng(3 + chunk_edge)
    x0 = chunk_edge * (grid.shape[0] // chunk_edge - 1)  # the last whole-chunk start: an edge tile
    shape = (grid.shape[0] - x0, *grid.shape[1:])
    for trial in range(12):
        lo = rng.integers(0, shape, size=(4, 3))
        hi = np.minimum(lo + rng.integers(0, 9, size=(4, 3)), shape)
        things = np.column_stack([np.arange(1, 5), lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2]])
        tile = np.zeros(shape, np.uint32)
        for ident, i0, i1, j0, j1, k0, k1 in things[:3]:  # the fourth box holds nothing
            part = tile[i0:i1, j0:j1, k0:k1]
            part[rng.random(part.shape) < 0.5] = ident * 1000 + trial
        occ.write_tile("s", grid, 0, "instance", tile, x0, occ.chunks_of_boxes("s", grid, "instance", things, shape))
        occ.write_boxes("s", grid, 1, "instance", tile, x0, things)
        assert _stored_chunks(occ, grid, "instance", 1) == _stored_chunks(occ, grid, "instance", 0)
        np.testing.assert_array_equal(occ.read_tile("s", grid, 1, "instance", x0, shape[0]), tile)


@pytest.mark.parametrize("chunk_edge", [16, 7])
def test_tiles_written_from_points_store_the_chunks_of_the_dense_tile(store, chunk_edge):
    # write_points against write_tile of the dense tile: the same chunk files and bytes; a chunk
    # whose points are all +0.0 is not stored, one holding a -0.0 is
    occ, grid = _tile_grid_store(store, chunk_edge)
    occ.create("s", grid, frame_count=2, chunk_edge=chunk_edge)
    rng = np.random.default_rng(11 + chunk_edge)
    shape = (min(2 * chunk_edge, grid.shape[0] - chunk_edge), *grid.shape[1:])  # 16: up to the array's end
    for n in (0, 1, 7, 300):
        flat = rng.choice(int(np.prod(shape)), size=n, replace=False)
        values = rng.normal(size=(n, 3)).astype(np.float16)
        values[: n // 3] = 0.0
        values[n // 3: n // 3 + 1] = -0.0
        dense = np.zeros((int(np.prod(shape)), 3), np.float16)
        dense[flat] = values
        occ.write_tile("s", grid, 0, "flow", dense.reshape(*shape, 3), chunk_edge)
        occ.write_points("s", grid, 1, "flow", chunk_edge, shape[0], flat, values)
        assert _stored_chunks(occ, grid, "flow", 1) == _stored_chunks(occ, grid, "flow", 0)
        got = occ.read_tile("s", grid, 1, "flow", chunk_edge, shape[0])
        np.testing.assert_array_equal(got.view(np.uint16), dense.reshape(*shape, 3).view(np.uint16))
    with pytest.raises(ValueError, match="outside the tile"):
        occ.write_points("s", grid, 1, "flow", 0, chunk_edge, np.array([chunk_edge * 25 * 10]), np.ones((1, 3)))
