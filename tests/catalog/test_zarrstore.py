"""The store contract of the frame-indexed Zarr hierarchies: every test runs on both
:class:`OccupancyStore` and :class:`SensorStore` (and on a local and a memory store). What is
specific to one store (x-tiles, grids, casting images, ``*_raw`` arrays) is tested in its own file."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
import zarr
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.catalog.occupancy import OccupancyStore, parse_output_key
from carlaocc.catalog.sensors import SensorStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.zarrio import ZSTD_LEVEL, encode_chunk, frame_fingerprint, parse_frame_key, zarr_store
from carlaocc.catalog.zarrstore import FrameArrayStore, chunk_flags
from carlaocc.pipeline.engine.runner import outputs_intact
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

GRID = GridSpec(region_min=(-2.0, -1.0, -0.5), region_max=(2.0, 1.5, 0.5), voxel_size=0.25)  # 16 x 10 x 4
W, H = 12, 8


@dataclass(frozen=True)
class Kind:
    """How the contract drives one store: its group, arrays and create call."""

    id: str
    cls: type[FrameArrayStore]
    group: object
    create: Callable  # (store object, frame_count, other: bool) -> replaced; other: a changed spec
    names: tuple[str, ...]  # arrays the contract writes: an integer one, a float one with a trailing axis
    frame_shape: tuple[int, ...]  # one frame of an array without trailing axes
    dims: list[str]
    read: Callable  # (store object, frame, name) -> the frame as the store's own reader returns it


def _create_occupancy(occ, frames, other=False):
    return occ.create("seq", GRID, frames, 4 if other else 8, extra_attrs={"lidar_to_ego": [[1.0, 0.0], [0.0, 1.0]]},
                      names=("semantic", "instance", "flow"))


def _create_sensors(sensors, frames, other=False):
    return sensors.create("seq", "cam", W + 4 * other, H, frames, ("depth", "semantic", "normal"),
                          extra_attrs={"K": [[10.0, 0.0, 6.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]]})


KINDS = [
    Kind("occupancy", OccupancyStore, GRID, _create_occupancy, ("semantic", "flow"), GRID.shape,
         ["frame", "x", "y", "z"], lambda s, t, n: s.read_frame("seq", GRID, t, (n,))[n]),
    Kind("sensors", SensorStore, "cam", _create_sensors, ("semantic", "normal"), (H, W),
         ["frame", "v", "u"], lambda s, t, n: s.read_image("seq", "cam", t, n)),
]


@pytest.fixture(params=KINDS, ids=[k.id for k in KINDS])
def kind(request) -> Kind:
    return request.param


def _data(s: FrameArrayStore, kind: Kind, name: str, rng) -> np.ndarray:
    """A random frame of array ``name``: sparse nonzero values, some chunks empty."""
    dtype, _, trailing = s.arrays[name]
    shape = (*kind.frame_shape, *trailing)
    keep = rng.random(kind.frame_shape) < 0.3
    keep[:8, :8] = False  # the first chunk (occupancy) holds nothing
    keep[-1, -1] = True
    if np.dtype(dtype).kind == "f":
        values = rng.uniform(-1.0, 80.0, shape)
    else:
        values = rng.integers(1, 30, shape)
    return (values * keep.reshape(*keep.shape, *(1,) * len(trailing))).astype(dtype)


def _frame_files(store, s: FrameArrayStore, kind: Kind, name: str, frame: int) -> list[str]:
    prefix = store.path(f"{s.zarr_root}/{s.array_path('seq', kind.group, name)}/c/{frame}")
    return sorted(store.fs.find(prefix)) if store.fs.exists(prefix) else []


def _through_zarr(store, s: FrameArrayStore, kind: Kind, name: str, frame: int) -> np.ndarray:
    root = zarr.open_group(store=zarr_store(store, s.zarr_root), mode="r")
    return root[s.array_path("seq", kind.group, name)][frame]


def test_create_and_exists(store, kind):
    s = kind.cls(store)
    assert not s.exists("seq", kind.group, kind.names[0])
    assert kind.create(s, 3) is False  # nothing replaced
    for name in kind.names:
        assert s.exists("seq", kind.group, name)
        assert not s.exists("seq", kind.group, name, 3) and not s.exists("seq", kind.group, name, -1)
        dtype, description, trailing = s.arrays[name]
        arr = s.open("seq", kind.group, name)
        assert arr.shape == (3, *kind.frame_shape, *trailing) and arr.chunks[0] == 1
        assert arr.dtype == np.dtype(dtype)
        attrs = s.attrs("seq", kind.group, name)
        assert attrs["dims"] == [*kind.dims, *(["component"] if trailing else [])]
        assert attrs["sequence_id"] == "seq" and attrs["taxonomy_version"] == TAXONOMY_VERSION
        assert list(attrs)[-1] == "description" and attrs["description"] == description
    # the declared codec pipeline is the one chunks are encoded with (catalog.zarrio)
    meta = json.loads(store.read_bytes(f"{s.zarr_root}/{s.array_path('seq', kind.group, kind.names[1])}/zarr.json"))
    assert [c["name"] for c in meta["codecs"]] == ["bytes", "zstd"]
    assert meta["codecs"][0]["configuration"]["endian"] == "little"  # a multi-byte dtype
    assert meta["codecs"][1]["configuration"]["level"] == ZSTD_LEVEL
    assert meta["fill_value"] == 0


def test_unknown_arrays_are_rejected(store, kind):
    s = kind.cls(store)
    with pytest.raises(ValueError, match=f"unknown {s.kind}.*colour"):
        s._create_arrays("seq", kind.group, ("colour",), 1, kind.frame_shape, kind.frame_shape, {"dims": []})


def test_write_a_frame_and_read_it_back(store, kind):
    s = kind.cls(store)
    kind.create(s, 3)
    rng = np.random.default_rng(0)
    data = {n: _data(s, kind, n, rng) for n in kind.names}
    out = s.write_frame("seq", kind.group, 1, data)
    assert list(out) == [s.output_key("seq", kind.group, n, 1) for n in kind.names]
    for name, want in data.items():
        key = s.output_key("seq", kind.group, name, 1)
        assert key == f"{s.zarr_root}/{s.array_path('seq', kind.group, name)}[1]"
        assert parse_frame_key(key) == (s.zarr_root, s.array_path("seq", kind.group, name), 1)
        for back in (kind.read(s, 1, name), s.read_frame("seq", kind.group, 1, (name,))[name],
                     _through_zarr(store, s, kind, name, 1)):
            assert back.dtype == want.dtype
            np.testing.assert_array_equal(back, want)
        assert s.exists("seq", kind.group, name, 1)
        for other in (0, 2):  # frames not written read as the fill value
            assert not kind.read(s, other, name).any()
            assert not _through_zarr(store, s, kind, name, other).any()


def test_empty_chunks_are_not_written(store, kind):
    s = kind.cls(store)
    kind.create(s, 2)
    integer, floating = kind.names
    rng = np.random.default_rng(1)
    data = _data(s, kind, integer, rng)
    s.write_frame("seq", kind.group, 0, {integer: np.zeros_like(data)})
    assert _frame_files(store, s, kind, integer, 0) == []
    s.write_frame("seq", kind.group, 0, {integer: data})
    assert _frame_files(store, s, kind, integer, 0)
    s.write_frame("seq", kind.group, 0, {integer: np.zeros_like(data)})  # rewritten empty: chunks removed
    assert _frame_files(store, s, kind, integer, 0) == []
    assert not kind.read(s, 0, integer).any()
    # data is bitwise: a -0.0 is stored
    neg = np.zeros_like(_data(s, kind, floating, rng))
    neg.reshape(-1)[-1] = -0.0
    s.write_frame("seq", kind.group, 1, {floating: neg})
    assert len(_frame_files(store, s, kind, floating, 1)) == 1
    assert np.signbit(kind.read(s, 1, floating).reshape(-1)[-1])


def test_fingerprints_follow_the_stored_chunks(store, kind):
    s = kind.cls(store)
    kind.create(s, 2)
    name = kind.names[0]
    path = s.array_path("seq", kind.group, name)
    data = _data(s, kind, name, np.random.default_rng(2))
    (key, fp), = s.write_frame("seq", kind.group, 1, {name: data}).items()
    assert s.fingerprints("seq", kind.group, 1, (name,)) == {key: fp}
    assert s.frame_fingerprint(path, 1) == fp == frame_fingerprint(store, s.zarr_root, path, 1)
    assert s.frame_fingerprint(path, 0) != fp  # another frame, no chunks
    assert s.write_frame("seq", kind.group, 1, {name: data.copy()})[key] == fp  # the same data: stable
    assert outputs_intact(store, {key: fp})
    # a temporary file left in the chunk directory is not part of the frame
    store.fs.pipe_file(store.path(f"{s.zarr_root}/{path}/c/1/.chunk-crashed"), b"junk")
    assert s.frame_fingerprint(path, 1) == fp
    changed = data.copy()
    changed.reshape(-1)[-1] += 1  # one element of one chunk
    fp2 = s.write_frame("seq", kind.group, 1, {name: changed})[key]
    assert fp2 != fp and not outputs_intact(store, {key: fp})
    store.fs.rm(_frame_files(store, s, kind, name, 1)[-1])  # a lost chunk
    assert s.frame_fingerprint(path, 1) not in (fp, fp2)
    assert s.frame_fingerprint(s.array_path("nope", kind.group, name), 1) is None


def test_a_chunk_is_encoded_as_the_bytes_of_its_contiguous_little_endian_copy():
    from numcodecs import Zstd

    rng = np.random.default_rng(5)
    tile = rng.integers(0, 3, (6, 40, 9)).astype(np.uint32)
    blocks = [tile[:, 8:24], tile[:, :16].astype(">u4"), tile[2:4, :16].astype(np.float64) * 1.5,
              tile[:, 24:40], tile[:1, :2]]  # sliced, big-endian, cast (truncated), then smaller ones
    for dtype in (np.uint32, np.int16):
        for block in blocks:
            want = Zstd(level=ZSTD_LEVEL).encode(np.ascontiguousarray(block, dtype=np.dtype(dtype).newbyteorder("<")))
            assert encode_chunk(block, dtype) == want


def test_a_frame_has_one_fingerprint_whether_listed_from_disk_or_through_fsspec(tmp_path):
    # a local store walks its chunk directories itself, an object store lists through fsspec:
    # the same frame (more than ten chunks a side: "/10" sorts before "/2") must hash the same
    import fsspec
    import uuid

    url = f"memory://carlaocc-test-{uuid.uuid4().hex}"
    fps = []
    for store in (Store(str(tmp_path / "root")), Store(url)):
        occ = OccupancyStore(store)
        occ.create("seq", GRID, 1, 1, names=("semantic",))
        data = _data(occ, KINDS[0], "semantic", np.random.default_rng(4))
        fps.append(occ.write_frame("seq", GRID, 0, {"semantic": data}))
        assert any("/c/0/10/" in f for f in _frame_files(store, occ, KINDS[0], "semantic", 0))
    fsspec.filesystem("memory").rm(Store(url).root, recursive=True)
    assert fps[0] == fps[1]


def test_create_again_keeps_the_same_spec_and_replaces_a_changed_one(store, kind):
    s = kind.cls(store)
    kind.create(s, 2)
    name = kind.names[0]
    data = _data(s, kind, name, np.random.default_rng(3))
    s.write_frame("seq", kind.group, 0, {name: data})
    assert kind.create(s, 2) is False  # the same spec: kept with its data
    np.testing.assert_array_equal(kind.read(s, 0, name), data)
    assert kind.create(s, 4) is True  # another frame count: replaced, its data gone
    assert s.open("seq", kind.group, name).shape[0] == 4
    assert not kind.read(s, 0, name).any() and _frame_files(store, s, kind, name, 0) == []
    assert kind.create(s, 4, other=True) is True  # another layout (occupancy: chunks; sensors: width)
    assert kind.create(s, 4, other=True) is False


def test_missing_arrays_are_named(store, kind):
    s = kind.cls(store)
    name = kind.names[0]
    where = f"{s.zarr_root}/{s.array_path('seq', kind.group, name)}"
    assert not s.exists("seq", kind.group, name, 0)
    for call in (lambda: s.open("seq", kind.group, name), lambda: s.attrs("seq", kind.group, name)):
        with pytest.raises(StoreError, match=f"missing in the store .*{where}"):
            call()
    with pytest.raises(ValueError, match=f"{where} does not exist"):
        s.write_frame("seq", kind.group, 0, {name: np.zeros(kind.frame_shape, np.uint8)})
    kind.create(s, 1)
    with pytest.raises(ValueError, match=f"{where}: frame 1 outside"):
        s.write_frame("seq", kind.group, 1, {name: _data(s, kind, name, np.random.default_rng(4))})


def test_damaged_arrays_are_named(store, kind):
    s = kind.cls(store)
    kind.create(s, 1)
    integer, floating = kind.names
    s.write_frame("seq", kind.group, 0, {integer: _data(s, kind, integer, np.random.default_rng(5))})
    # a chunk that does not decode
    chunk = _frame_files(store, s, kind, integer, 0)[-1]
    store.fs.pipe_file(chunk, store.fs.cat_file(chunk)[:5])
    ipath = s.array_path("seq", kind.group, integer)
    for read in (lambda: kind.read(s, 0, integer), lambda: s.read_frame("seq", kind.group, 0, (integer,))):
        with pytest.raises(StoreError, match=f"damaged .*{s.zarr_root}/{ipath}"):
            read()
    # metadata that does not parse
    fpath = s.array_path("seq", kind.group, floating)
    store.fs.pipe_file(store.path(f"{s.zarr_root}/{fpath}/zarr.json"), b"{not json")
    for call in (lambda: s.open("seq", kind.group, floating), lambda: s.exists("seq", kind.group, floating)):
        with pytest.raises(StoreError, match=f"damaged .*{s.zarr_root}/{fpath}"):
            call()


def test_layouts_read_from_the_metadata_are_zarrs(store, kind):
    # the writers' layout (shape, chunks, dtype) is parsed from each array's zarr.json: the same
    # as zarr-python's view of every array the store knows, created and replaced
    s = kind.cls(store)
    for other in (False, True):
        kind.create(s, 3, other)
        s = kind.cls(store)  # a fresh store object: nothing cached
        root = zarr.open_group(store=zarr_store(store, s.zarr_root), mode="r")
        for name in kind.names:
            arr = root[s.array_path("seq", kind.group, name)]
            assert s._layout("seq", kind.group, name) == (arr.shape, arr.chunks, np.dtype(arr.dtype))
    # a damaged root (or array metadata) falls back to zarr, which names the damage
    store.fs.pipe_file(store.path(f"{s.zarr_root}/zarr.json"), b"{not json")
    with pytest.raises(StoreError, match=f"damaged .*{s.zarr_root}"):
        kind.cls(store)._layout("seq", kind.group, kind.names[0])


def test_frame_keys():
    assert parse_frame_key("occupancy.zarr/s/0.25/semantic[12]") == ("occupancy.zarr", "s/0.25/semantic", 12)
    assert parse_frame_key("sensors.zarr/s/cam/depth[3]") == ("sensors.zarr", "s/cam/depth", 3)
    assert parse_output_key("occupancy.zarr/s/0.25/semantic[12]") == ("s/0.25/semantic", 12)
    assert parse_output_key("sensors.zarr/s/cam/depth[3]") is None
    for plain in ("lidar/s/000001.parquet", "scenes/frames/s.parquet", "x.zarr[1]", "a/b[1]", "x.zarr/[1]"):
        assert parse_frame_key(plain) is None


@settings(max_examples=80, deadline=None)
@given(nx=st.integers(1, 9), ny=st.integers(1, 9), nz=st.integers(1, 11), cx=st.integers(1, 4), cy=st.integers(1, 4),
       dtype=st.sampled_from(["uint8", "uint32", "float16"]), trailing=st.sampled_from([(), (3,)]),
       seed=st.integers(0, 2**32 - 1))
def test_chunk_flags_match_a_numpy_reference(nx, ny, nz, cx, cy, dtype, trailing, seed):
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
