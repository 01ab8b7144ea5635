"""Stat signatures: change with every rewrite, never read a chunk, ETags where the store has them."""

from __future__ import annotations

import os
import uuid

import numpy as np
import pytest

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.signatures import (external_signature, file_signature, frame_signature, info_signature,
                                         output_signature, output_signatures)
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.runner import outputs_problem
from carlaocc.schemas.grid import GridSpec

GRID = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(6.4, 3.2, 1.6), voxel_size=0.4)  # 16 x 8 x 4


def test_info_signature_prefers_the_etag():
    assert info_signature({"size": 3, "ETag": '"abc"', "LastModified": "x"}) == "etag:abc"
    assert info_signature({"size": 3, "mtime": 1.5}) == "3:1.5"
    assert info_signature({"size": 3}) is None  # neither version nor time: never trusted


@pytest.mark.parametrize("url", ["local", "memory"])
def test_file_signature_changes_with_a_rewrite(tmp_path, url):
    store = Store(str(tmp_path) if url == "local" else f"memory://sig-{uuid.uuid4().hex}")
    assert file_signature(store, "a.bin") is None
    store.write_bytes("a.bin", b"one")
    first = file_signature(store, "a.bin")
    assert first == file_signature(store, "a.bin")
    store.write_bytes("a.bin", b"two")  # same size, rewritten by rename
    assert file_signature(store, "a.bin") != first


def _frame(store: Store):
    occ = OccupancyStore(store)
    occ.create("seq", GRID, 2, 8, names=("semantic",))
    sem = np.zeros(GRID.shape, np.uint8)
    sem[1, 1, 1] = 3
    outputs = occ.write_frame("seq", GRID, 1, {"semantic": sem})
    return occ, sem, outputs


def test_frame_signature_follows_the_chunks_not_their_bytes(tmp_path):
    store = Store(str(tmp_path))
    occ, sem, outputs = _frame(store)
    (key,) = outputs
    path = OccupancyStore.array_path("seq", GRID, "semantic")
    sig = frame_signature(store, "occupancy.zarr", path, 1)
    assert sig == output_signature(store, key) and sig.startswith("stat:")
    assert frame_signature(store, "occupancy.zarr", OccupancyStore.array_path("nope", GRID, "semantic"), 1) is None
    # a temporary file left by a crashed write is not part of the frame
    chunk_dir = store.path(f"occupancy.zarr/{path}/c/1")
    open(os.path.join(chunk_dir, ".chunk-tmp"), "wb").close()
    assert frame_signature(store, "occupancy.zarr", path, 1) == sig
    # another chunk of the frame: another signature
    sem[12, 1, 1] = 4
    occ.write_frame("seq", GRID, 1, {"semantic": sem})
    assert frame_signature(store, "occupancy.zarr", path, 1) != sig


def test_outputs_trusted_while_signatures_hold(tmp_path):
    store = Store(str(tmp_path))
    occ, sem, outputs = _frame(store)
    store.write_bytes("t.parquet", b"x" * 10)
    outputs["t.parquet"] = store.fingerprint("t.parquet")
    sigs = output_signatures(store, outputs)
    assert outputs_problem(store, outputs, signatures=sigs) is None
    # bytes changed in place, size and modification time put back: the ctime moved, so seen
    (chunk,) = [p for p in store.fs.find(store.path("occupancy.zarr")) if "/c/1/" in p]
    st = os.stat(chunk)
    with open(chunk, "r+b") as f:
        f.write(b"\0" * st.st_size)
    os.utime(chunk, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert outputs_problem(store, outputs, signatures=sigs).startswith("outputs damaged: occupancy.zarr/seq/")
    assert outputs_problem(store, outputs).startswith("outputs damaged: occupancy.zarr/seq/")
    # a group's metadata is still checked
    store.remove("occupancy.zarr/seq/zarr.json")
    fresh = output_signatures(store, outputs)
    assert outputs_problem(store, outputs, signatures=fresh) == "outputs damaged: occupancy.zarr/seq/zarr.json missing"


def test_external_signature(tmp_path):
    f = tmp_path / "m.obj"
    assert external_signature(str(f)) is None
    f.write_text("v 0 0 0\n")
    assert external_signature(str(f)) == external_signature(str(f)) is not None
