"""External occupancy formats (catalog.formats): real samples, round trips, refusals, corrupt files."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carlaocc.catalog.formats import FormatError, atomic_write, occ3d, semantickitti, surroundocc
from carlaocc.catalog.formats import carlaocc_npz as cnpz
from carlaocc.catalog.formats.carlaocc_npz import load_carlaocc_npz, save_carlaocc_npz
from carlaocc.catalog.formats.occ3d import Occ3DFrame, load_occ3d, save_occ3d
from carlaocc.catalog.formats.semantickitti import (
    SemanticKittiVoxels,
    load_semantickitti,
    save_semantickitti,
)
from carlaocc.catalog.formats.surroundocc import (
    dense_to_surroundocc,
    load_surroundocc,
    save_surroundocc,
    surroundocc_to_dense,
)
from shared_data import needs, shared_path

TESTDATA = shared_path("occupancy")
OCC3D_SAMPLE = TESTDATA / "occ3d-nuscenes" / "labels.npz"
SKITTI_YAML = TESTDATA / "semantic-kitti" / "semantic-kitti.yaml"
SURROUND_POINTS = TESTDATA / "surroundocc-own-data" / "pc_seman__pc_seman_0.npy"


# --------------------------------------------------------------------------------------- shared


def test_format_error_is_value_error():
    assert issubclass(FormatError, ValueError)


def test_atomic_write_leaves_old_file_on_crash(tmp_path):
    target = tmp_path / "f.bin"
    target.write_bytes(b"old")

    def boom(fh):
        fh.write(b"half")
        raise RuntimeError("crash")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["f.bin"]  # no temp file left behind


# ---------------------------------------------------------------------------------------- Occ3D


@needs(OCC3D_SAMPLE)
def test_occ3d_real_sample_round_trip(tmp_path):
    frame = load_occ3d(OCC3D_SAMPLE)
    assert frame.semantics.shape == occ3d.OCC3D_SHAPE and frame.semantics.dtype == np.uint8
    assert frame.semantics.max() == occ3d.OCC3D_FREE
    out = tmp_path / "sub" / "labels.npz"
    save_occ3d(out, frame)
    again = load_occ3d(str(out))
    for key in occ3d.OCC3D_KEYS:
        np.testing.assert_array_equal(getattr(again, key), getattr(frame, key))
    # same container: compressed members, same names in the same order, same dtypes/shapes
    ref, new = zipfile.ZipFile(OCC3D_SAMPLE), zipfile.ZipFile(out)
    assert [i.filename for i in new.infolist()] == [i.filename for i in ref.infolist()]
    assert {i.compress_type for i in ref.infolist()} == {zipfile.ZIP_DEFLATED}
    assert {i.compress_type for i in new.infolist()} == {zipfile.ZIP_DEFLATED}
    # the deflated arrays are bit-identical (only zip header versions depend on numpy)
    assert [(i.CRC, i.compress_size) for i in new.infolist()] == [(i.CRC, i.compress_size) for i in ref.infolist()]
    with np.load(OCC3D_SAMPLE) as a, np.load(out) as b:
        assert {k: (a[k].dtype, a[k].shape) for k in a.files} == {k: (b[k].dtype, b[k].shape) for k in b.files}


def test_occ3d_rejects_bad_arrays(tmp_path):
    ok = np.zeros((4, 4, 2), np.uint8)
    with pytest.raises(FormatError, match="uint8"):
        save_occ3d(tmp_path / "a.npz", Occ3DFrame(ok.astype(np.int32), ok, ok))
    with pytest.raises(FormatError, match="shape"):
        save_occ3d(tmp_path / "a.npz", Occ3DFrame(ok, ok[:2], ok))
    np.savez_compressed(tmp_path / "missing.npz", semantics=ok, mask_lidar=ok)
    with pytest.raises(FormatError, match="mask_camera") as e:
        load_occ3d(tmp_path / "missing.npz")
    assert "missing.npz" in str(e.value)
    np.savez_compressed(tmp_path / "mask.npz", semantics=ok, mask_lidar=ok + 2, mask_camera=ok)
    with pytest.raises(FormatError, match="0/1"):
        load_occ3d(tmp_path / "mask.npz")
    assert not (tmp_path / "a.npz").exists()


# -------------------------------------------------------------------------------- SemanticKITTI


@needs(SKITTI_YAML)
def test_semantickitti_learning_maps_match_yaml():
    cfg = yaml.safe_load(SKITTI_YAML.read_text())
    assert semantickitti.LEARNING_MAP == cfg["learning_map"]
    assert semantickitti.LEARNING_MAP_INV == cfg["learning_map_inv"]
    raw = np.array(list(cfg["learning_map"]))
    np.testing.assert_array_equal(semantickitti.to_learning(raw), list(cfg["learning_map"].values()))
    learning = np.arange(20)
    np.testing.assert_array_equal(semantickitti.to_raw(learning), [cfg["learning_map_inv"][i] for i in learning])
    # inverse of a learning id maps back to it
    np.testing.assert_array_equal(semantickitti.to_learning(semantickitti.to_raw(learning)), learning)


def test_semantickitti_maps_refuse_unknown_ids():
    with pytest.raises(ValueError, match="2"):
        semantickitti.to_learning(np.array([[0, 2], [10, 10]]))
    with pytest.raises(ValueError, match="65535"):
        semantickitti.to_learning(np.array([65535], np.uint16))
    with pytest.raises(ValueError, match="20"):
        semantickitti.to_raw(np.array([0, 20]))
    assert semantickitti.to_learning(np.array([[252, 40]], np.uint16)).tolist() == [[1, 9]]


def _skitti_voxels(seed: int = 0) -> SemanticKittiVoxels:
    rng = np.random.default_rng(seed)
    shape = semantickitti.SEMANTICKITTI_SHAPE
    raw = np.array(list(semantickitti.LEARNING_MAP), np.uint16)
    labels = np.zeros(shape, np.uint16)
    occupied = rng.random(shape) < 0.05
    labels[occupied] = rng.choice(raw, occupied.sum())
    return SemanticKittiVoxels(
        occupied=occupied, invalid=rng.random(shape) < 0.3, occluded=rng.random(shape) < 0.2, labels=labels
    )


def test_semantickitti_round_trip_and_bit_layout(tmp_path):
    vox = _skitti_voxels()
    paths = save_semantickitti(tmp_path / "voxels", "000000", vox)
    assert {p.name for p in paths.values()} == {"000000.bin", "000000.invalid", "000000.occluded", "000000.label"}
    assert paths["bin"].stat().st_size == 256 * 256 * 32 // 8
    assert paths["label"].stat().st_size == 256 * 256 * 32 * 2
    back = load_semantickitti(tmp_path / "voxels", "000000")
    for f in ("occupied", "invalid", "occluded", "labels"):
        np.testing.assert_array_equal(getattr(back, f), getattr(vox, f))
    assert back.occupied.dtype == bool and back.labels.dtype == np.uint16

    # independent decoding, the semantic-kitti-api way: bit 7 of byte 0 is voxel (0, 0, 0),
    # C order; labels little-endian uint16
    b = np.fromfile(paths["occluded"], dtype=np.uint8)
    bits = np.stack([(b >> (7 - k)) & 1 for k in range(8)], axis=1).reshape(-1)
    np.testing.assert_array_equal(bits.reshape(256, 256, 32).astype(bool), vox.occluded)
    np.testing.assert_array_equal(np.fromfile(paths["label"], dtype="<u2").reshape(256, 256, 32), vox.labels)


def test_semantickitti_single_voxel_bit_position(tmp_path):
    shape = semantickitti.SEMANTICKITTI_SHAPE
    occ = np.zeros(shape, bool)
    occ[0, 0, 1] = True  # flat index 1 -> byte 0, second most significant bit
    occ[0, 1, 0] = True  # flat index 32 -> byte 4, most significant bit
    z = np.zeros(shape, bool)
    save_semantickitti(tmp_path, "s", SemanticKittiVoxels(occ, z, z, np.zeros(shape, np.uint16)))
    data = (tmp_path / "s.bin").read_bytes()
    assert data[0] == 0b0100_0000 and data[4] == 0b1000_0000 and sum(data) == 0b0100_0000 + 0b1000_0000


def test_semantickitti_writer_rejects_wrong_shape(tmp_path):
    z = np.zeros((8, 8, 8), bool)
    with pytest.raises(FormatError, match="shape"):
        save_semantickitti(tmp_path, "x", SemanticKittiVoxels(z, z, z, z.astype(np.uint16)))
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------- SurroundOcc


def _voxelize_points(points: np.ndarray) -> np.ndarray:
    """Points (x, y, z, label) in the LiDAR frame -> dense uint8 labels at 0.5 m (255 = free)."""
    lo = np.array(surroundocc.SURROUNDOCC_RANGE[:3])
    ijk = np.floor((points[:, :3] - lo) / surroundocc.SURROUNDOCC_VOXEL_SIZE).astype(np.int64)
    inside = ((ijk >= 0) & (ijk < surroundocc.SURROUNDOCC_SHAPE)).all(axis=1)
    dense = np.full(surroundocc.SURROUNDOCC_SHAPE, 255, np.uint8)
    dense[tuple(ijk[inside].T)] = points[inside, 3].astype(np.uint8)  # last point wins
    return dense


@needs(SURROUND_POINTS)
def test_surroundocc_round_trip_real_points(tmp_path):
    dense = _voxelize_points(np.load(SURROUND_POINTS))
    rows = dense_to_surroundocc(dense, free=255)
    assert rows.dtype == np.int64 and rows.shape[1] == 4 and len(rows) > 1000
    assert (np.diff(np.ravel_multi_index(tuple(rows[:, :3].T), dense.shape)) > 0).all()  # C order
    assert 0 in rows[:, 3]  # nuScenes noise label 0 is kept as a row
    save_surroundocc(tmp_path / "frame.npy", rows)
    raw = np.load(tmp_path / "frame.npy")
    assert raw.dtype == np.int64 and raw.shape == rows.shape  # what SurroundOcc's np.save wrote
    back = load_surroundocc(tmp_path / "frame.npy")
    np.testing.assert_array_equal(back, rows)
    np.testing.assert_array_equal(surroundocc_to_dense(back, free=255), dense)


def test_surroundocc_validation(tmp_path):
    with pytest.raises(FormatError, match="x index out of range"):
        save_surroundocc(tmp_path / "a.npy", np.array([[200, 0, 0, 1]]))
    np.save(tmp_path / "b.npy", np.array([[0, 0, 16, 1]], np.int64))
    with pytest.raises(FormatError, match="z index") as e:
        load_surroundocc(tmp_path / "b.npy")
    assert "b.npy" in str(e.value)
    np.save(tmp_path / "c.npy", np.zeros((3, 3), np.int64))
    with pytest.raises(FormatError, match=r"\(N, 4\)"):
        load_surroundocc(tmp_path / "c.npy")
    np.save(tmp_path / "d.npy", np.zeros((3, 4), np.float32))
    with pytest.raises(FormatError, match="integers"):
        load_surroundocc(tmp_path / "d.npy")
    # an unsigned label beyond int64 is refused, not wrapped to a negative one
    np.save(tmp_path / "e.npy", np.array([[0, 0, 0, 2**64 - 4]], np.uint64))
    with pytest.raises(FormatError, match=r"label 18446744073709551612 does not fit"):
        load_surroundocc(tmp_path / "e.npy")
    with pytest.raises(ValueError, match="free label"):
        surroundocc_to_dense(np.array([[0, 0, 0, 0]]), free=0)
    with pytest.raises(ValueError, match="more than once"):
        surroundocc_to_dense(np.array([[1, 1, 1, 3], [1, 1, 1, 4]]), free=0)
    # other grids: any shape passed explicitly
    rows = np.array([[3, 2, 1, 7]])
    np.testing.assert_array_equal(dense_to_surroundocc(surroundocc_to_dense(rows, (4, 3, 2), free=0), 0), rows)


# ------------------------------------------------------------------------------- CarlaOcc npz


def _sparse_frame(rng, shape, n_sem=30, max_inst=2047, density=0.05):
    sem = np.where(rng.random(shape) < density, rng.integers(1, n_sem, shape), 0).astype(np.uint8)
    inst = np.where(sem > 0, rng.integers(0, max_inst + 1, shape), 0).astype(np.uint32)
    return sem, inst


def test_carlaocc_npz_round_trip_and_layout(tmp_path):
    rng = np.random.default_rng(1)
    sem, inst = _sparse_frame(rng, (40, 30, 12))
    sem[0, 0, 0], inst[0, 0, 0] = 31, 2047  # the extremes fit
    save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.2, (-25.6, -25.6, -3.0))
    with np.load(tmp_path / "f.npz") as z:
        assert set(z.files) == {"occupancy", "voxel_size", "voxel_origin", "volume_size"}
        occ = z["occupancy"]
        assert occ.dtype == np.uint16 and occ.shape == (np.count_nonzero(sem), 4)
        assert occ[0].tolist() == [0, 0, 0, 31 << 11 | 2047]  # the release's code: semantic << 11 | instance
        assert z["volume_size"].tolist() == [40, 30, 12]
        assert float(z["voxel_size"]) == 0.2 and z["voxel_origin"].tolist() == [-25.6, -25.6, -3.0]
    assert {i.compress_type for i in zipfile.ZipFile(tmp_path / "f.npz").infolist()} == {zipfile.ZIP_DEFLATED}
    back = load_carlaocc_npz(tmp_path / "f.npz")
    np.testing.assert_array_equal(back.semantic, sem)
    np.testing.assert_array_equal(back.instance, inst)
    assert back.semantic.dtype == np.uint8 and back.instance.dtype == np.uint32
    assert back.voxel_size == 0.2 and back.voxel_origin == (-25.6, -25.6, -3.0)


def test_carlaocc_npz_refuses_instead_of_wrapping(tmp_path):
    sem = np.zeros((4, 4, 4), np.uint8)
    inst = np.zeros((4, 4, 4), np.uint32)
    sem[1, 1, 1], inst[1, 1, 1] = 14, 2048
    sem[2, 2, 2], inst[2, 2, 2] = 14, 5000
    with pytest.raises(FormatError, match=r"instance id 5000 exceeds 2047") as e:
        save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.1, (0, 0, 0))
    assert "f.npz" in str(e.value)
    inst[2, 2, 2] = 0
    with pytest.raises(FormatError, match=r"instance id 2048 exceeds 2047"):
        save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.1, (0, 0, 0))
    with pytest.raises(FormatError, match=r"instance id 2048 exceeds 999 \(the decimal encoding"):
        save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.1, (0, 0, 0), "decimal")
    inst[1, 1, 1] = 3
    sem[3, 3, 3] = 32
    with pytest.raises(FormatError, match=r"semantic id 32 exceeds 31"):
        save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.1, (0, 0, 0))
    sem[3, 3, 3] = 0
    inst[0, 0, 0] = 9
    with pytest.raises(FormatError, match="free voxel"):
        save_carlaocc_npz(tmp_path / "f.npz", sem, inst, 0.1, (0, 0, 0))
    big = np.zeros((65537, 1, 1), np.uint8)
    with pytest.raises(FormatError, match=r"voxel index 65536 exceeds 65535"):
        save_carlaocc_npz(tmp_path / "f.npz", big, big.astype(np.uint32), 0.1, (0, 0, 0))
    assert not (tmp_path / "f.npz").exists()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    shape=st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 5)),
    density=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**32 - 1),
    voxel_size=st.floats(0.01, 2.0),
    origin=st.tuples(*[st.floats(-100, 100)] * 3),
)
def test_carlaocc_npz_hypothesis_identity(tmp_path, shape, density, seed, voxel_size, origin):
    rng = np.random.default_rng(seed)
    encoding = ("bits", "decimal")[seed % 2]
    sem, inst = _sparse_frame(rng, shape, n_sem=32 if encoding == "bits" else 65, density=density,
                              max_inst=2047 if encoding == "bits" else 999)
    path = tmp_path / "h.npz"
    save_carlaocc_npz(path, sem, inst, voxel_size, origin, encoding)
    back = load_carlaocc_npz(path)
    np.testing.assert_array_equal(back.semantic, sem)
    np.testing.assert_array_equal(back.instance, inst)
    assert back.voxel_size == voxel_size and back.voxel_origin == origin


def test_carlaocc_npz_loader_validates(tmp_path):
    good = {"voxel_size": np.float64(0.1), "voxel_origin": np.zeros(3), "volume_size": np.array([4, 4, 4])}
    np.savez_compressed(tmp_path / "a.npz", occupancy=np.array([[4, 0, 0, 1 << 11]], np.uint16), **good)
    with pytest.raises(FormatError, match="x index 4 outside"):
        load_carlaocc_npz(tmp_path / "a.npz")
    np.savez_compressed(tmp_path / "b.npz", occupancy=np.array([[0, 0, 0, 5]], np.uint16), **good)
    with pytest.raises(FormatError, match="semantic 0"):
        load_carlaocc_npz(tmp_path / "b.npz")
    np.savez_compressed(tmp_path / "c.npz", occupancy=np.zeros((1, 4), np.int32), **good)
    with pytest.raises(FormatError, match="uint16"):
        load_carlaocc_npz(tmp_path / "c.npz")
    np.savez_compressed(tmp_path / "d.npz", occupancy=np.zeros((0, 4), np.uint16), voxel_size=np.float64(0.1))
    with pytest.raises(FormatError, match="voxel_origin"):
        load_carlaocc_npz(tmp_path / "d.npz")
    np.savez_compressed(tmp_path / "e.npz", occupancy=np.zeros((0, 4), np.uint16), label_encoding=np.asarray("hex"),
                        **good)
    with pytest.raises(FormatError, match="unknown label_encoding 'hex'"):
        load_carlaocc_npz(tmp_path / "e.npz")


# ------------------------------------------------------------------------ corrupt / truncated


def _truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def _corrupt_middle(path: Path) -> None:
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = b"\xff" * 64
    path.write_bytes(bytes(data))


def _occ3d_file(tmp_path):
    z = np.zeros((20, 20, 4), np.uint8)
    p = tmp_path / "labels.npz"
    save_occ3d(p, Occ3DFrame(z + 17, z, z + 1))
    return p, lambda: load_occ3d(p)


def _surroundocc_file(tmp_path):
    p = tmp_path / "frame.npy"
    save_surroundocc(p, np.array([[1, 2, 3, 4]] * 1 + [[5, 6, 7, 8]]))
    return p, lambda: load_surroundocc(p)


def _carlaocc_file(tmp_path):
    rng = np.random.default_rng(0)
    sem, inst = _sparse_frame(rng, (30, 30, 8), density=0.3)
    p = tmp_path / "frame.npz"
    save_carlaocc_npz(p, sem, inst, 0.1, (0, 0, 0))
    return p, lambda: load_carlaocc_npz(p)


@pytest.mark.parametrize("make", [_occ3d_file, _surroundocc_file, _carlaocc_file], ids=["occ3d", "surroundocc", "carlaocc"])
@pytest.mark.parametrize("damage", ["truncate", "truncate_tiny", "corrupt", "empty", "garbage"])
def test_loaders_reject_damaged_files(tmp_path, make, damage):
    path, load = make(tmp_path)
    load()  # intact file loads
    if damage == "truncate":
        _truncate(path)
    elif damage == "truncate_tiny":
        _truncate(path, 0.05)
    elif damage == "corrupt":
        _corrupt_middle(path)
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        path.write_bytes(b"not an array at all" * 10)
    with pytest.raises(FormatError) as e:
        load()
    assert str(path) in str(e.value)


@pytest.mark.parametrize("ext", ["bin", "invalid", "occluded", "label"])
@pytest.mark.parametrize("delta", [-1, 1])
def test_semantickitti_rejects_wrong_file_sizes(tmp_path, ext, delta):
    shape = semantickitti.SEMANTICKITTI_SHAPE
    z = np.zeros(shape, bool)
    paths = save_semantickitti(tmp_path, "000123", SemanticKittiVoxels(z, z, z, np.zeros(shape, np.uint16)))
    data = paths[ext].read_bytes()
    paths[ext].write_bytes(data[:-1] if delta < 0 else data + b"\0")
    with pytest.raises(FormatError, match="truncated" if delta < 0 else "too long") as e:
        load_semantickitti(tmp_path, "000123")
    assert str(paths[ext]) in str(e.value)


def test_missing_files_raise_file_not_found(tmp_path):
    for load in (
        lambda: load_occ3d(tmp_path / "none.npz"),
        lambda: load_surroundocc(tmp_path / "none.npy"),
        lambda: load_carlaocc_npz(tmp_path / "none.npz"),
        lambda: load_semantickitti(tmp_path, "none"),
    ):
        with pytest.raises(FileNotFoundError):
            load()


def test_package_reexports():
    from carlaocc.catalog import formats

    for name in formats.__all__:
        assert hasattr(formats, name), name
    assert formats.save_carlaocc_npz is cnpz.save_carlaocc_npz


def test_atomic_write_uses_umask_permissions(tmp_path):
    import os

    old = os.umask(0o022)
    try:
        path = atomic_write(tmp_path / "p.bin", lambda fh: fh.write(b"x"))
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644


# -- layouts: the registry, label grids, sequences -------------------------------------------------
def test_layout_registry_and_label_grids(tmp_path):
    from carlaocc.catalog.formats import FORMATS, DatasetInputError, dataset_format
    from carlaocc.catalog.formats.layout import collect_inputs, group_sequences, read_frame

    assert list(FORMATS) == ["occ3d", "semantickitti", "surroundocc", "carlaocc-npz"]
    with pytest.raises(DatasetInputError, match="unknown format 'nusc'; choose one of occ3d, semantickitti"):
        dataset_format("nusc")
    # Occ3D: free 17 -> 0, class k -> k + 1, the camera mask, the nuScenes geometry
    sem = np.full(occ3d.OCC3D_SHAPE, 17, np.uint8)
    sem[1, 2, 3], sem[4, 5, 6] = 0, 16
    cam = np.ones(occ3d.OCC3D_SHAPE, np.uint8)
    cam[0, 0, 0] = 0
    for tok in ("b1", "a2"):
        save_occ3d(tmp_path / "gts/scene-1" / tok / "labels.npz", Occ3DFrame(sem, cam, cam))
    fmt = FORMATS["occ3d"]
    files = [i.path for i in collect_inputs(fmt, [tmp_path / "gts"])]
    assert [fmt.frame_token(f) for f in files] == ["a2", "b1"]  # path order: sample tokens carry no time
    assert group_sequences(fmt, files) == [(str(tmp_path / "gts/scene-1"), files)]
    grid = read_frame(fmt, files[0])
    assert (grid.semantic[1, 2, 3], grid.semantic[4, 5, 6], grid.semantic[0, 0, 1]) == (1, 17, 0)
    assert not grid.mask[0, 0, 0] and grid.mask[0, 0, 1]
    assert grid.voxel_size == 0.4 and grid.origin == (-40.0, -40.0, -1.0)
    assert fmt.class_names[fmt.to_dataset_id(17)] == "vegetation"
    # SurroundOcc: label k -> k + 1 (its "noise" 0 is a class), a missing row is free
    save_surroundocc(tmp_path / "so/7.npy", np.array([[0, 0, 0, 0], [1, 2, 3, 16]]))
    grid = read_frame(FORMATS["surroundocc"], tmp_path / "so/7.npy")
    assert (grid.semantic[0, 0, 0], grid.semantic[1, 2, 3], int(grid.semantic.sum())) == (1, 17, 18)
    assert grid.mask is None and FORMATS["surroundocc"].class_names[0] == "noise"
    # an unreadable file is named once
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetInputError, match="bad.npz: unreadable") as err:
        read_frame(FORMATS["carlaocc-npz"], tmp_path / "bad.npz")
    assert str(err.value).count("bad.npz") == 1
