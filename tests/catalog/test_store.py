import os

import numpy as np
import pytest

from carlaocc.catalog.meshes import MeshStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.meshes import MeshPart
from carlaocc.schemas.records import QuarantineRecord


def _q(reason: str) -> QuarantineRecord:
    return QuarantineRecord(stage="ingest", source="folder", source_path="x.obj", reason=reason, hint="h")


def test_write_is_atomic_on_failure(store, monkeypatch):
    table = ParquetTable(store, QuarantineRecord)
    table.save("k", [_q("first")])
    before = store.read_bytes(table.path("k"))

    # a crash in the middle of writing the new bytes
    real_open = type(store.fs).open

    def crashing_open(self, path, mode="rb", *a, **kw):
        fh = real_open(self, path, mode, *a, **kw)
        if "w" in mode:
            def boom(data):
                raise OSError("disk full")
            fh.write = boom
        return fh

    def failing_put(self, path, value, **kw):  # an object store's one PUT fails as a whole
        raise OSError("disk full")

    monkeypatch.setattr(type(store.fs), "open", crashing_open)
    monkeypatch.setattr(type(store.fs), "pipe_file", failing_put)
    with pytest.raises(OSError, match="disk full"):
        table.save("k", [_q("second")])
    monkeypatch.undo()
    # the old file is intact and no temporary file is left behind
    assert store.read_bytes(table.path("k")) == before
    assert table.load()[0].reason == "first"
    leftovers = [p for p in store.fs.find(store.root) if ".tmp-" in p]
    assert leftovers == []


def test_glob_never_lists_temporary_files(store):
    store.write_bytes("t/a.parquet", b"x")
    store.fs.pipe(store.path("t/.tmp-123-b.parquet.partial"), b"y")
    assert store.glob("t", ".parquet") == ["t/a.parquet"]


def test_fingerprint_changes_with_content(store):
    a = store.write_bytes("f.bin", b"one")
    assert store.fingerprint("f.bin") == a
    b = store.write_bytes("f.bin", b"two")
    assert a != b and store.fingerprint("f.bin") == b
    assert store.fingerprint("missing.bin") is None


def test_missing_file_error_names_it(store):
    with pytest.raises(StoreError, match="nope/x.parquet"):
        store.read_bytes("nope/x.parquet")


def test_unwritable_root(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(StoreError, match="is a file"):
        Store(str(f)).check_writable()
    with pytest.raises(StoreError, match="not writable"):
        Store(str(f / "below-a-file")).check_writable()
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o500)
    try:
        if os.access(ro, os.W_OK):  # running as root: permissions are not enforced
            pytest.skip("root ignores directory permissions")
        with pytest.raises(StoreError, match="not writable"):
            Store(str(ro / "sub")).check_writable()
    finally:
        os.chmod(ro, 0o700)


def test_check_writable_leaves_nothing(store):
    store.check_writable()
    assert not store.fs.exists(store.root) or store.fs.find(store.root) == []
    if store.is_local:
        import os

        assert not os.path.exists(store.root)  # nothing created, not even the root


def test_mesh_round_trip(store):
    import trimesh

    box = trimesh.creation.box((4.0, 2.0, 1.5))
    cyl = trimesh.creation.cylinder(0.3, 0.2)
    parts = [MeshPart("body", box.vertices, box.faces, 14), MeshPart("wheel", cyl.vertices, cyl.faces, 14)]
    meshes = MeshStore(store)
    fp = meshes.save("admesh/meshes/x.glb", parts)
    assert fp == meshes.save("admesh/meshes/x.glb", parts)  # deterministic bytes
    back = meshes.load("admesh/meshes/x.glb")
    assert len(back) == 2
    for p, (v, f) in zip(parts, back):
        np.testing.assert_allclose(v, p.vertices, atol=1e-6)  # float32 in glTF
        np.testing.assert_array_equal(f, p.faces)
    # stored Y-up as glTF requires: the box's 1.5 m height is along glTF's y
    import io

    scene = trimesh.load(io.BytesIO(store.read_bytes("admesh/meshes/x.glb")), file_type="glb", force="scene")
    assert scene.geometry["p000"].extents[1] == pytest.approx(1.5)


def test_mesh_load_error_names_path(store):
    store.write_bytes("admesh/meshes/bad.glb", b"not a glb")
    with pytest.raises(StoreError, match="bad.glb"):
        MeshStore(store).load("admesh/meshes/bad.glb")


@pytest.mark.parametrize("name", ["victim::x/new", "a#b", "q?x=1", "p%20c", "sp ace", "[br]"])
def test_a_local_root_is_a_path_whatever_its_characters(tmp_path, name):
    # '::' once made fsspec chain filesystems: the root became the folder before it, another dataset
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text("x")
    store = Store(str(tmp_path / name))
    assert store.root == str(tmp_path / name)
    store.write_bytes("f.txt", b"1")
    assert (tmp_path / name / "f.txt").read_bytes() == b"1"
    assert sorted(p.name for p in victim.iterdir()) == ["keep.txt"]


def test_a_chained_url_is_refused():
    with pytest.raises(ValueError, match="'::' chains filesystems"):
        Store("file:///tmp/a::memory://b")


def test_files_honour_the_umask(tmp_path):
    # a shared root: chunks, tables and meshes readable by the group when the umask says so
    from carlaocc.catalog.zarrio import put_object

    store = Store(str(tmp_path / "root"))
    old = os.umask(0o022)
    try:
        put_object(store, "occupancy.zarr/s/0.2/semantic/c/0/0/0/0", b"chunk")
        store.write_bytes("scenes/t.parquet", b"table")
    finally:
        os.umask(old)
    for rel in ("occupancy.zarr/s/0.2/semantic/c/0/0/0/0", "scenes/t.parquet"):
        assert os.stat(tmp_path / "root" / rel).st_mode & 0o777 == 0o644, rel


@pytest.mark.parametrize("below", ["", "sub"])
def test_a_dangling_link_root_is_refused_up_front(tmp_path, below):
    (tmp_path / "root").symlink_to(tmp_path / "nowhere")
    store = Store(str(tmp_path / "root" / below) if below else str(tmp_path / "root"))
    with pytest.raises(StoreError, match="symbolic link to .*nowhere, which does not exist"):
        store.check_writable()
    assert not (tmp_path / "nowhere").exists()
