"""Damaged artefacts are stale, not fatal: what the catalog says about unreadable Zarr metadata,
chunks, Parquet tables and lineage files, and how creating the arrays again repairs them (on a
local and a memory store)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.catalog.lineage import DAMAGED_SUFFIX, LineageLog
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable, parquet_problem, read_parquet
from carlaocc.catalog.sensors import SensorStore
from carlaocc.catalog.store import StoreError
from carlaocc.catalog.zarrio import (encode_chunk, frame_fingerprint, is_damaged, metadata_problem, parse_metadata,
                                     zstd_frame_ok)
from carlaocc.pipeline.engine.runner import outputs_problem
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import QuarantineRecord, RunRecord

GRID = GridSpec(region_min=(-2.0, -1.0, -0.5), region_max=(2.0, 1.5, 0.5), voxel_size=0.25)  # 16 x 10 x 4
NAMES = ("semantic", "instance")
GARBAGE = b"\x00garbage\xff" * 3


def _damage(store, rel: str, how: str = "truncate") -> None:
    data = store.fs.cat_file(store.path(rel))
    store.fs.pipe_file(store.path(rel), data[: len(data) // 2] if how == "truncate" else GARBAGE)


def _occupancy(store) -> tuple[OccupancyStore, np.ndarray, dict[str, str]]:
    """Two frames of semantic and instance, frame 1 written; (store, its semantic, lineage)."""
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 2, 8, names=NAMES)
    rng = np.random.default_rng(0)
    sem = (rng.integers(1, 30, GRID.shape) * (rng.random(GRID.shape) < 0.3)).astype(np.uint8)
    outputs = occ.write_frame("seq", GRID, 1, {"semantic": sem, "instance": sem.astype(np.uint32) * 7})
    return occ, sem, outputs


def _path(name: str) -> str:
    return f"occupancy.zarr/{OccupancyStore.array_path('seq', GRID, name)}"


# -- zstd frames and metadata ---------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["uint8", "uint32", "float16"]), st.floats(0.0, 1.0))
def test_a_stored_chunk_is_a_whole_zstd_frame_and_no_prefix_of_it_is(seed, dtype, density):
    rng = np.random.default_rng(seed)
    block = (rng.integers(0, 200, (8, 8, 4)) * (rng.random((8, 8, 4)) < density)).astype(dtype)
    payload = encode_chunk(block, dtype)
    assert zstd_frame_ok(payload, block.nbytes)
    assert not zstd_frame_ok(payload, block.nbytes + 1)  # the header's content size is checked
    cut = int(rng.integers(0, len(payload)))
    assert not zstd_frame_ok(payload[:cut], block.nbytes)  # any truncation
    assert not zstd_frame_ok(payload + b"\x00", block.nbytes)  # bytes after the frame
    assert not zstd_frame_ok(GARBAGE) and not zstd_frame_ok(b"")


def test_metadata_must_be_zarr_v3_of_the_right_kind():
    array = {"zarr_format": 3, "node_type": "array", "shape": [2, 4], "data_type": "uint8", "codecs": [],
             "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [1, 4]}}}
    group = {"zarr_format": 3, "node_type": "group", "attributes": {}}
    assert parse_metadata(json.dumps(array).encode(), "array") == array
    assert parse_metadata(json.dumps(group).encode(), "group") == group
    assert parse_metadata(json.dumps(group).encode(), "array") is None
    for bad in (b"", GARBAGE, json.dumps(array).encode()[:-5], b"[]", b'{"zarr_format": 2, "node_type": "group"}',
                json.dumps({**array, "shape": "x"}).encode(), json.dumps({**array, "chunk_grid": {}}).encode()):
        assert parse_metadata(bad) is None, bad


def test_metadata_problem_names_missing_and_unreadable(store):
    occ, _, _ = _occupancy(store)
    assert metadata_problem(store, _path("semantic"), "array") is None
    assert metadata_problem(store, "occupancy.zarr", "group") is None
    assert metadata_problem(store, _path("nope"), "array") == "missing"
    _damage(store, f"{_path('semantic')}/zarr.json")
    assert metadata_problem(store, _path("semantic"), "array") == "unreadable"


# -- fingerprints ----------------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["truncate", "garbage"])
@pytest.mark.parametrize("victim", ["array", "group", "sequence", "root", "chunk"])
def test_a_damaged_frame_has_a_damaged_fingerprint_naming_the_file(store, victim, how):
    occ, _, outputs = _occupancy(store)
    assert outputs_problem(store, outputs) is None
    rel = {"array": f"{_path('semantic')}/zarr.json",
           "group": f"occupancy.zarr/seq/{GRID.key}/zarr.json",
           "sequence": "occupancy.zarr/seq/zarr.json",
           "root": "occupancy.zarr/zarr.json",
           "chunk": sorted(store.glob(f"{_path('semantic')}/c/1", ""))[-1]}[victim]
    _damage(store, rel, how)
    fp = frame_fingerprint(store, "occupancy.zarr", OccupancyStore.array_path("seq", GRID, "semantic"), 1)
    assert is_damaged(fp) and fp == f"damaged: {rel} unreadable"
    assert outputs_problem(store, outputs) == f"outputs damaged: {rel} unreadable"
    if victim == "chunk":  # the other frame and array are intact
        assert not is_damaged(occ.frame_fingerprint(OccupancyStore.array_path("seq", GRID, "semantic"), 0))
        assert not is_damaged(occ.frame_fingerprint(OccupancyStore.array_path("seq", GRID, "instance"), 1))


def test_a_missing_group_metadata_is_damage_and_a_missing_array_is_not(store):
    _, _, outputs = _occupancy(store)
    store.fs.rm(store.path(f"occupancy.zarr/seq/{GRID.key}/zarr.json"))
    assert outputs_problem(store, outputs) == f"outputs damaged: occupancy.zarr/seq/{GRID.key}/zarr.json missing"
    store.remove(_path("semantic"))
    assert frame_fingerprint(store, "occupancy.zarr", OccupancyStore.array_path("seq", GRID, "semantic"), 1) is None


def test_outputs_problem_tells_damage_from_modification(store):
    _, sem, outputs = _occupancy(store)
    t = ParquetTable(store, QuarantineRecord)
    rec = QuarantineRecord(stage="t", source="t", source_path="t", reason="r", hint="")
    outputs[t.path("a")] = t.save("a", [rec])
    assert outputs_problem(store, outputs) is None
    t.save("a", [rec, rec])  # rewritten: readable, other bytes
    assert outputs_problem(store, outputs) == "outputs missing or modified"
    _damage(store, t.path("a"))
    assert outputs_problem(store, outputs) == f"outputs damaged: {t.path('a')} unreadable"
    store.remove(t.path("a"))
    assert outputs_problem(store, outputs) == "outputs missing or modified"


# -- reading a damaged store -----------------------------------------------------------------------
def test_reading_damaged_metadata_or_chunks_is_a_store_error_naming_them(store):
    occ, _, _ = _occupancy(store)
    chunk = sorted(store.glob(f"{_path('semantic')}/c/1", ""))[-1]
    _damage(store, chunk, "garbage")
    with pytest.raises(StoreError, match=chunk.replace("/", ".")):
        OccupancyStore(store).read_frame("seq", GRID, 1, ("semantic",))
    _damage(store, f"{_path('instance')}/zarr.json")
    with pytest.raises(StoreError, match="damaged.*instance"):
        OccupancyStore(store).open("seq", GRID, "instance")


# -- creating again repairs ------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["truncate", "garbage"])
def test_create_replaces_an_array_whose_metadata_is_unreadable(store, how):
    occ, sem, _ = _occupancy(store)
    _damage(store, f"{_path('semantic')}/zarr.json", how)
    assert occ.create("seq", GRID, 2, 8, names=NAMES) is True  # replaced: its frames must be written again
    assert not occ.read_frame("seq", GRID, 1, ("semantic",))["semantic"].any()
    assert store.glob(f"{_path('semantic')}/c", "") == []
    np.testing.assert_array_equal(occ.read_frame("seq", GRID, 1, ("instance",))["instance"], sem.astype(np.uint32) * 7)
    assert occ.create("seq", GRID, 2, 8, names=NAMES) is False


@pytest.mark.parametrize("victim", ["occupancy.zarr/zarr.json", "occupancy.zarr/seq/zarr.json", "group"])
@pytest.mark.parametrize("how", ["truncate", "garbage", "delete"])
def test_create_rewrites_damaged_group_metadata_and_keeps_the_arrays(store, victim, how):
    occ, sem, outputs = _occupancy(store)
    rel = f"occupancy.zarr/seq/{GRID.key}/zarr.json" if victim == "group" else victim
    before = store.fs.cat_file(store.path(rel))
    if how == "delete":
        store.fs.rm(store.path(rel))
    else:
        _damage(store, rel, how)
    assert occ.create("seq", GRID, 2, 8, names=NAMES) is False  # nothing of the arrays was lost
    assert store.fs.cat_file(store.path(rel)) == before  # written again as it was
    assert outputs_problem(store, outputs) is None
    np.testing.assert_array_equal(OccupancyStore(store).read_frame("seq", GRID, 1, ("semantic",))["semantic"], sem)


def test_create_deletes_a_damaged_array_it_drops_anyway(store):
    occ, _, _ = _occupancy(store)
    occ.create("seq", GRID, 2, 8, names=NAMES + ("flow",))
    _damage(store, f"{_path('flow')}/zarr.json")
    assert occ.create("seq", GRID, 2, 8, names=NAMES) is False
    assert not store.exists(_path("flow"))


def test_sensor_store_repairs_like_the_occupancy_store(store):
    s = SensorStore(store)
    names = ("depth", "semantic")
    s.create("seq", "cam", 12, 8, 2, names)
    img = np.arange(96, dtype=np.uint8).reshape(8, 12)
    s.write_image("seq", "cam", 1, "semantic", img)
    _damage(store, "sensors.zarr/seq/cam/zarr.json", "garbage")
    assert s.create("seq", "cam", 12, 8, 2, names) is False
    np.testing.assert_array_equal(SensorStore(store).read_image("seq", "cam", 1, "semantic"), img)
    _damage(store, "sensors.zarr/seq/cam/depth/zarr.json")
    assert s.create("seq", "cam", 12, 8, 2, names) is True
    np.testing.assert_array_equal(SensorStore(store).read_image("seq", "cam", 1, "semantic"), img)
    # a recorder's raw input with damaged metadata is never deleted by the recorded path
    s.create("seq", "cam", 12, 8, 2, ("depth_raw",), keep_others=True)
    _damage(store, "sensors.zarr/seq/cam/depth_raw/zarr.json")
    damaged_raw = store.fs.cat_file(store.path("sensors.zarr/seq/cam/depth_raw/zarr.json"))
    assert s.create("seq", "cam", 12, 8, 2, names, keep_others=True) is False
    assert store.fs.cat_file(store.path("sensors.zarr/seq/cam/depth_raw/zarr.json")) == damaged_raw


# -- Parquet tables and lineage --------------------------------------------------------------------
@pytest.mark.parametrize("how", ["truncate", "garbage"])
def test_a_damaged_table_file_is_a_store_error_naming_it(store, how):
    t = ParquetTable(store, QuarantineRecord)
    t.save("a", [QuarantineRecord(stage="t", source="t", source_path="t", reason="r", hint="")])
    assert parquet_problem(store, t.path("a")) is None
    _damage(store, t.path("a"), how)
    assert parquet_problem(store, t.path("a")) == "unreadable"
    with pytest.raises(StoreError, match=f"{t.path('a')} is not a readable Parquet file"):
        t.load()
    with pytest.raises(StoreError, match=t.path("a")):
        read_parquet(store, t.path("a"))
    assert parquet_problem(store, "admesh/nope.parquet") == "missing"


def test_a_table_file_of_other_columns_is_a_store_error(store):
    runs, other = ParquetTable(store, RunRecord), ParquetTable(store, QuarantineRecord)
    runs.save("x", [])
    store.write_bytes(other.path("x"), store.read_bytes(runs.path("x")))
    with pytest.raises(StoreError, match="does not have its table's columns"):
        other.load()


def _run(run_id: str, partition: str) -> RunRecord:
    from datetime import datetime, timezone

    now = datetime(2026, 1, 1, tzinfo=timezone.utc)
    return RunRecord(run_id=run_id, stage="s", partition=partition, code_version="c", config_hash="h",
                     cache_key="k", input_fingerprints="{}", output_fingerprints="{}", status="completed",
                     started_at=now, ended_at=now, host="h", error="")


@pytest.mark.parametrize("how", ["truncate", "garbage"])
def test_an_unreadable_lineage_file_is_skipped_noted_and_set_aside(store, how):
    log = LineageLog(store)
    log.append("s", "r1", [_run("r1", "p0"), _run("r1", "p1")])
    path = log.append("s", "r2", [_run("r2", "p1")]) and "catalog/runs/stage=s/r2.parquet"
    log.append("t", "r1", [_run("r1", "q")])
    _damage(store, path, how)
    bytes_before = store.fs.cat_file(store.path(path))
    log = LineageLog(store)
    latest = log.latest("s")  # p1's newest record is lost: its older one is the latest readable
    assert {k: r.run_id for k, r in latest.items()} == {"p0": "r1", "p1": "r1"}
    assert log.damaged == {path: "unreadable"} and log.damaged_files("s") == [path] and log.damaged_files("t") == []
    assert [r.partition for r in log.load("t")] == ["q"]
    assert store.exists(path)  # reading writes nothing
    assert log.set_aside("t") == []
    assert log.set_aside("s") == [path + DAMAGED_SUFFIX]
    assert not store.exists(path) and store.fs.cat_file(store.path(path + DAMAGED_SUFFIX)) == bytes_before
    fresh = LineageLog(store)
    assert len(fresh.load()) == 3 and fresh.damaged == {}


def test_a_chunk_of_another_size_fails_even_into_a_reused_buffer(store):
    """Reads decode into a reused buffer: a chunk whose zstd frame holds fewer bytes than a chunk
    is a StoreError, never the previous chunk's bytes showing through."""
    from numcodecs import Zstd

    occ, sem, _ = _occupancy(store)
    full = np.full(GRID.shape, 5, np.uint8)
    occ.write_frame("seq", GRID, 0, {"semantic": full})
    victim = sorted(store.glob(f"{_path('semantic')}/c/1", ""))[0]
    store.fs.pipe_file(store.path(victim), Zstd(level=1).encode(np.zeros(10, np.uint8)))
    x = occ.read_tile("seq", GRID, 0, "semantic", 0, GRID.shape[0])  # fills the reused buffer with 5s
    assert (x == 5).all()
    with pytest.raises(StoreError, match="damaged chunk"):
        occ.read_tile("seq", GRID, 1, "semantic", 0, GRID.shape[0])


def test_frames_read_block_major_equal_the_frames_and_never_show_stale_blocks(store):
    """``read_blocks`` decodes each chunk into its block of a reused buffer: the blocks are the
    frame (``BlockedGrid.to_dense``), a chunk not stored reads as zeros over whatever the buffer
    held, and a chunk of another size is a StoreError."""
    from numcodecs import Zstd

    from carlaocc.stages.quality.blocks import BlockedGrid

    occ, sem, _ = _occupancy(store)
    occ.write_frame("seq", GRID, 0, {"semantic": np.full(GRID.shape, 5, np.uint8)})
    buf = occ.read_blocks("seq", GRID, 0, "semantic")
    assert buf.shape == (2, 2, 8, 8, GRID.shape[2])  # 16 x 10 in chunks of 8: the y edge is padded
    np.testing.assert_array_equal(BlockedGrid(buf, GRID.shape).to_dense(), 5)
    # frame 1 into the same buffer: the 5s of frame 0 must not survive where frame 1 has no chunk
    occ.read_blocks("seq", GRID, 1, "semantic", out=buf)
    np.testing.assert_array_equal(BlockedGrid(buf, GRID.shape).to_dense(), sem)
    np.testing.assert_array_equal(BlockedGrid(buf, GRID.shape).to_dense(),
                                  occ.read_tile("seq", GRID, 1, "semantic", 0, GRID.shape[0]))
    with pytest.raises(ValueError, match="blocks are"):
        occ.read_blocks("seq", GRID, 1, "semantic", out=np.empty((2, 2, 8, 8, 3), np.uint8))
    victim = sorted(store.glob(f"{_path('semantic')}/c/1", ""))[0]
    store.fs.pipe_file(store.path(victim), Zstd(level=1).encode(np.zeros(10, np.uint8)))
    with pytest.raises(StoreError, match="damaged chunk"):
        occ.read_blocks("seq", GRID, 1, "semantic", out=buf)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["uint8", "uint32"]))
def test_zstd_content_size_reads_the_frame_header(seed, dtype):
    from carlaocc.catalog.zarrio import zstd_content_size

    rng = np.random.default_rng(seed)
    block = rng.integers(0, 3, tuple(rng.integers(1, 40, 3))).astype(dtype)
    payload = encode_chunk(block, dtype)
    assert zstd_content_size(payload) == block.nbytes
    assert zstd_content_size(GARBAGE) is None and zstd_content_size(b"") is None
