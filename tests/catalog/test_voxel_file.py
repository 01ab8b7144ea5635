"""``carlaocc voxelize``'s output files (catalog/voxel_file.py): every layout written -> read ->
the same voxels; the sparse npz read with numpy alone as its docstring says; bad files refused
with the file's name."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from carlaocc.catalog.voxel_file import VOXEL_FILE_VERSION, VoxelFileError, load_voxels, save_voxels
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.voxels import SparseVoxels

GRID = GridSpec(region_min=(-1.5, 2.0, -0.25), region_max=(1.7, 4.4, 1.35), voxel_size=0.1)  # 32 x 24 x 16


def _random_dense(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    shape = GRID.shape
    semantic = np.where(rng.random(shape) < 0.03, rng.integers(1, 256, shape), 0).astype(np.uint8)
    instance = np.where((semantic > 0) & (rng.random(shape) < 0.5), rng.integers(1, 2**32, shape), 0).astype(np.uint32)
    semantic[0, 0, 0] = semantic[-1, -1, -1] = 7  # the first and last voxels: index 0 and the end
    return semantic, instance


def _same_grid(a: GridSpec, b: GridSpec) -> None:
    """The same voxels (a file keeps origin, shape and voxel size, not how the region was given)."""
    assert a.origin == b.origin and a.shape == b.shape and a.voxel_size == b.voxel_size


def _same(a: SparseVoxels, b: SparseVoxels) -> None:
    _same_grid(a.grid, b.grid)
    np.testing.assert_array_equal(a.index, b.index)
    np.testing.assert_array_equal(a.semantic, b.semantic)
    np.testing.assert_array_equal(a.instance, b.instance)
    assert a.semantic.dtype == np.uint8 and a.instance.dtype == np.uint32


@pytest.mark.parametrize("name, dense", [("v.npz", False), ("v.npz", True), ("v.zarr", False)])
def test_round_trip_gives_the_same_dense_arrays(tmp_path, name, dense):
    semantic, instance = _random_dense()
    voxels = SparseVoxels.from_dense(GRID, semantic, instance)
    assert len(voxels) == np.count_nonzero(semantic)
    save_voxels(voxels, tmp_path / name, dense=dense)
    back = load_voxels(tmp_path / name)
    _same(back, voxels)
    s2, i2 = back.dense()
    np.testing.assert_array_equal(s2, semantic)
    np.testing.assert_array_equal(i2, instance)
    assert [p.name for p in tmp_path.iterdir()] == [name]  # nothing left beside it


def test_sparse_npz_reads_with_numpy_alone(tmp_path):
    semantic, instance = _random_dense(1)
    save_voxels(SparseVoxels.from_dense(GRID, semantic, instance), tmp_path / "v.npz")
    d = np.load(tmp_path / "v.npz")
    assert str(d["format"]) == "carlaocc.voxels" and int(d["format_version"]) == VOXEL_FILE_VERSION
    assert str(d["layout"]) == "sparse" and "semantic" not in d.files  # an old reader fails by name
    assert d["voxel_index"].dtype == np.uint32 and np.all(np.diff(d["voxel_index"].astype(np.int64)) > 0)
    # the recipe of the module docstring and the command's --help
    sem = np.zeros(d["shape"], np.uint8)
    sem.flat[d["voxel_index"]] = d["voxel_semantic"]
    inst = np.zeros(d["shape"], np.uint32)
    inst.flat[d["voxel_index"]] = d["voxel_instance"]
    np.testing.assert_array_equal(sem, semantic)
    np.testing.assert_array_equal(inst, instance)
    np.testing.assert_allclose(d["voxel_origin"], GRID.origin)
    assert float(d["voxel_size"]) == 0.1
    ijk = np.stack(np.unravel_index(d["voxel_index"], d["shape"]), axis=1)
    assert (semantic[tuple(ijk.T)] > 0).all()
    # the index is stored, the labels deflated
    with zipfile.ZipFile(tmp_path / "v.npz") as zf:
        kinds = {i.filename: i.compress_type for i in zf.infolist()}
    assert kinds["voxel_index.npy"] == zipfile.ZIP_STORED and kinds["voxel_semantic.npy"] == zipfile.ZIP_DEFLATED


def test_zarr_skips_empty_chunks_and_keeps_the_grid_attributes(tmp_path):
    import zarr

    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(30.0, 14.0, 0.4), voxel_size=0.1)  # 300 x 140 x 4
    semantic = np.zeros(grid.shape, np.uint8)
    semantic[5, 3, 1] = 2  # one voxel: one chunk of (3 x 2) in x and y
    save_voxels(SparseVoxels.from_dense(grid, semantic, np.zeros(grid.shape, np.uint32)), tmp_path / "one.zarr")
    g = zarr.open_group(str(tmp_path / "one.zarr"), mode="r")
    assert g["semantic"].chunks == (128, 128, 4) and g["semantic"].attrs["voxel_size"] == 0.1
    assert g["semantic"].nchunks_initialized == 1 and g["instance"].nchunks_initialized == 0
    np.testing.assert_array_equal(g["semantic"][...], semantic)
    assert not g["instance"][...].any()


def test_empty_grid_round_trips(tmp_path):
    empty = SparseVoxels.from_dense(GRID, np.zeros(GRID.shape, np.uint8), np.zeros(GRID.shape, np.uint32))
    save_voxels(empty, tmp_path / "e.npz")
    back = load_voxels(tmp_path / "e.npz")
    _same_grid(back.grid, GRID)
    assert len(back) == 0 and not back.dense()[0].any()


def test_bad_files_are_refused_naming_them(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(VoxelFileError, match="junk.npz"):
        load_voxels(junk)
    other = tmp_path / "other.npz"
    np.savez(other, points=np.zeros(3))
    with pytest.raises(VoxelFileError, match="other.npz: holds neither"):
        load_voxels(other)
    newer = tmp_path / "newer.npz"
    np.savez(newer, format=np.str_("carlaocc.voxels"), format_version=np.int64(VOXEL_FILE_VERSION + 1),
             voxel_index=np.zeros(0, np.uint32))
    with pytest.raises(VoxelFileError, match="newer.npz: .* version 2: .*update carlaocc"):
        load_voxels(newer)
    with pytest.raises(VoxelFileError, match="must end in .npz or .zarr"):
        save_voxels(SparseVoxels.from_dense(GRID, *_random_dense()), tmp_path / "v.txt")
    assert not (tmp_path / "v.txt").exists()
