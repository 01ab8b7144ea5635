"""Issue 38: carlaocc.data.CarlaOccDataset reads the official release's layout. The shared built
root (default_01, 0.1 m, one camera) is exported with ``carlaocc export carlaocc-release`` and read
back through the loader: the same samples, the same keys but those the layout cannot hold, and
equal arrays (to the precision of the layout's text and PNG encodings) where it holds them."""

from __future__ import annotations

import json
import pickle
import shutil

import numpy as np
import pytest

from carlaocc.catalog.carla_recording import DEPTH_RANGE
from carlaocc.data import CarlaOccDataset, CarlaOccReleaseDataset, DatasetError

MAPS = ("depth", "semantic", "normal")
NOT_HELD = {"occ_flow", "occ_mask_camera", "occ_mask_lidar", "points_semantic", "points_instance", "points_channel",
            "boxes", "box_pose", "box_velocity", "box_instance", "box_semantic"}  # fmt: skip
"""Keys of a built root's sample that the release layout cannot hold (absent from a release's)."""
CROP = ((2.0, -6.0, -2.5), (14.3, 6.0, 1.0))


@pytest.fixture(scope="module")
def pair(default_01, release_01):
    ours = CarlaOccDataset(default_01.url, voxel_size=0.1, camera_maps=MAPS)
    rel = CarlaOccDataset(str(release_01), voxel_size=0.1, camera_maps=MAPS)
    return ours, rel


def test_a_release_folder_gives_a_release_dataset_with_our_samples(pair):
    ours, rel = pair
    assert isinstance(rel, CarlaOccReleaseDataset) and isinstance(rel, CarlaOccDataset)
    assert type(ours) is CarlaOccDataset
    # our sequence ids (from the export's note) and every frame, in the same order
    assert rel.samples == ours.samples and len(rel) == len(ours) > 0
    # the plan is ours less what the layout cannot hold
    plan_ours = {k for keys in ours.key_plan().values() for k in keys}
    plan_rel = {k for keys in rel.key_plan().values() for k in keys}
    assert plan_rel == plan_ours - NOT_HELD


def test_every_frame_keeps_its_poses_and_grid(default_01, release_01):
    kw = dict(occupancy="none", cameras=False, lidar=False, boxes=False)
    ours, rel = CarlaOccDataset(default_01.url, voxel_size=0.1, **kw), CarlaOccDataset(str(release_01), **kw)
    assert rel.voxel_size == 0.1  # the finest release grid, as on our roots
    for n in range(len(ours)):
        a, b = ours[n], rel[n]
        assert set(b) == set(a)
        assert (b["sequence_id"], b["frame_index"]) == (a["sequence_id"], a["frame_index"])
        assert b["timestamp"] == pytest.approx(a["timestamp"], abs=1e-9)
        for key in ("lidar_pose", "ego_pose", "lidar_to_ego", "grid_origin", "grid_shape"):
            np.testing.assert_allclose(b[key], a[key], atol=2e-6, err_msg=key)


def test_samples_round_trip_where_the_layout_holds_them(pair, release_01):
    ours, rel = pair
    step = np.float32(DEPTH_RANGE / 65535)
    # the export renumbered some of this root's instance ids (moving ones 1000 + id % 1000): the
    # note maps them back
    note = json.loads((release_01 / "carlaocc_export.json").read_text())
    assert any(int(k.split(":")[1]) != v for ids in note["instances"].values() for k, v in ids.items())
    # frame 1 of the first two sequences (sparse 0.1 m reads of the busier ones take seconds each)
    for n in (1, 3):
        a, b = ours[n], rel[n]
        assert set(b) == set(a) - NOT_HELD, (n, set(a) ^ set(b))
        assert (b["sequence_id"], b["frame_index"]) == (a["sequence_id"], a["frame_index"])
        assert b["timestamp"] == pytest.approx(a["timestamp"], abs=1e-9)
        assert b["voxel_size"] == a["voxel_size"]
        np.testing.assert_array_equal(b["grid_shape"], a["grid_shape"])
        np.testing.assert_allclose(b["grid_origin"], a["grid_origin"], atol=1e-9)
        # poses: the release's %.6f text; the ego from the authors' 1.73 m LiDAR mount (ours on this rig)
        for key in ("lidar_pose", "ego_pose", "lidar_to_ego"):
            np.testing.assert_allclose(b[key], a[key], atol=2e-6, err_msg=key)
        # occupancy: every voxel, class and (mapped back) instance id exactly
        assert len(a["occ"]) > 1000 and a["occ_instance"].any()
        np.testing.assert_array_equal(b["occ"], a["occ"])
        np.testing.assert_array_equal(b["occ_instance"], a["occ_instance"])
        assert b["occ"].dtype == np.int32 and b["occ_instance"].dtype == np.uint32
        # cameras: calibration to the yaml's 6 decimals; RGB and classes exact; depth and normals
        # within half a quantization step of their PNGs
        assert b["camera_names"] == a["camera_names"]
        for key in ("cam_intrinsics", "cam_to_lidar", "cam_to_ego"):
            np.testing.assert_allclose(b[key], a[key], atol=2e-6, err_msg=key)
        np.testing.assert_array_equal(b["images"], a["images"])
        np.testing.assert_array_equal(b["cam_semantic"], a["cam_semantic"])
        # (the PNGs stop at 80 m: farther surfaces read as none, 0, like the sky)
        near = (a["cam_depth"] > 0) & (a["cam_depth"] < DEPTH_RANGE - step)
        assert near.any() and (~near).any()
        assert (b["cam_depth"][~near] == 0).all() and (b["cam_depth"][near] > 0).all()
        np.testing.assert_allclose(b["cam_depth"][near], a["cam_depth"][near], atol=step / 2 + 1e-4)
        assert b["cam_normal"].dtype == np.float16 and b["cam_depth"].dtype == np.float32
        np.testing.assert_allclose(b["cam_normal"].astype(np.float32), a["cam_normal"].astype(np.float32),
                                   atol=1 / 255 + 2e-3)
        # LiDAR: the PLY's 4 decimals
        assert b["points"].shape == a["points"].shape and b["points"].dtype == np.float32
        np.testing.assert_allclose(b["points"], a["points"], atol=6e-5)


def test_dense_crop_and_coarse_grids(default_01, release_01):
    kw = dict(cameras=False, lidar=False, boxes=False)
    a = CarlaOccDataset(default_01.url, voxel_size=0.1, occupancy="crop", crop=CROP, **kw)[1]
    b = CarlaOccDataset(str(release_01), voxel_size=0.1, occupancy="crop", crop=CROP, **kw)[1]
    assert set(b) == set(a) - {"flow", "mask_camera", "mask_lidar"}
    np.testing.assert_array_equal(b["crop_offset"], a["crop_offset"])
    assert a["semantic"].any()
    for key in ("semantic", "instance"):
        assert b[key].dtype == a[key].dtype
        np.testing.assert_array_equal(b[key], a[key], err_msg=key)
    # the surround-view grid: its own shape and origin, the export's voxels
    c = CarlaOccDataset(str(release_01), voxel_size=0.4, **kw)
    s = c[1]
    np.testing.assert_array_equal(s["grid_shape"], (128, 128, 16))
    np.testing.assert_allclose(s["grid_origin"], (-25.6, -25.6, -2.4))
    assert len(s["occ"]) and (s["occ"][:, :3].max(axis=0) < (128, 128, 16)).all()
    # it pickles to DataLoader workers as a release dataset
    c2 = pickle.loads(pickle.dumps(c))
    assert type(c2) is CarlaOccReleaseDataset and c2.samples == c.samples
    np.testing.assert_array_equal(c2[1]["occ"], s["occ"])


def test_splits_and_refusals(default_01, release_01, tmp_path):
    kw = dict(cameras=False, lidar=False, boxes=False, occupancy="none")
    for split in ("train", "val", "test"):
        try:
            want = CarlaOccDataset(default_01.url, split=split, voxel_size=0.1, **kw).samples
        except DatasetError:
            want = None
        if want is None:
            with pytest.raises(DatasetError):
                CarlaOccDataset(str(release_01), split=split, **kw)
        else:
            assert CarlaOccDataset(str(release_01), split=split, **kw).samples == want
    with pytest.raises(DatasetError, match="holds no camera instance maps"):
        CarlaOccDataset(str(release_01), camera_maps=("instance",))
    with pytest.raises(DatasetError, match=r"voxel_size=0\.3: the release's grids are 0\.1 m \(vs_0_1\)"):
        CarlaOccDataset(str(release_01), voxel_size=0.3)
    # without our note: the release's folder names and ids, 10 Hz
    bare = tmp_path / "bare"
    shutil.copytree(release_01, bare, ignore=shutil.ignore_patterns("rgb", "depth", "semantics", "normal", "lidar"))
    (bare / "carlaocc_export.json").unlink()
    d = CarlaOccDataset(str(bare), cameras=False, lidar=False)
    seq, frame = d.samples[1]
    assert seq.startswith("Town") and "_Opt_Seq" in seq and d[1]["timestamp"] == pytest.approx(frame / 10.0)
    # a missing image is one line naming the file and the option
    with pytest.raises(DatasetError, match=r"rgb/image_00/0000\.png is missing: pass cameras=False"):
        CarlaOccDataset(str(bare), lidar=False)[0]
