"""carlaocc.data.CarlaOccDataset on a built root (the embedded default at 0.1 m, two frames a
sequence, camera_00): the sample index and splits, sparse occupancy equal to the stored frame and
gathered from that frame's chunks only, crops, boxes that hold their instance's voxels and land on
their instance's pixels, clear errors, and a real torch DataLoader with two workers (the snippet of
docs/tutorials/train.md runs in tests/pipeline/test_tutorials.py)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.schemas.grid import GridSpec

from carlaocc.data import CarlaOccDataset, DatasetError, collate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ds(default_01):
    return CarlaOccDataset(default_01.url, camera_maps=("instance",))


def test_index_splits_and_voxel_size(default_01, ds):
    n_frames = query(default_01, "SELECT count(*) FROM frames")[1][0][0]
    assert ds.voxel_size == 0.1 and len(ds) == n_frames == 6
    assert ds.samples == sorted(ds.samples)
    parts = {s: CarlaOccDataset(default_01.url, split=s, cameras=False, lidar=False) for s in ("train", "val", "test")}
    assert sum(len(p) for p in parts.values()) == len(ds)
    for split, part in parts.items():
        listed = set(default_01.read_bytes(f"splits/{split}.txt").decode().split())
        assert {s for s, _ in part.samples} == listed
    with pytest.raises(IndexError):
        ds[len(ds)]
    assert ds[-1]["frame_index"] == ds.samples[-1][1]


def test_sparse_occupancy_is_the_stored_frame_read_from_its_own_chunks(default_01, ds, monkeypatch):
    import carlaocc.catalog.zarrstore as zs

    read: list[str] = []
    real = zs.get_object
    monkeypatch.setattr(zs, "get_object", lambda store, key: (read.append(key), real(store, key))[1])
    seq, frame = ds.samples[1]
    s = ds[1]
    # only this frame's chunks were read (every chunk key is <array>/c/<frame>/...)
    chunk_keys = [k for k in read if "/c/" in k]
    assert chunk_keys and all(f"/c/{frame}/" in k for k in chunk_keys)
    d = OccupancyStore(default_01).read_frame(seq, GridSpec(voxel_size=0.1), frame, ("semantic", "instance"))
    i, j, k = np.nonzero(d["semantic"])
    np.testing.assert_array_equal(s["occ"], np.column_stack([i, j, k, d["semantic"][i, j, k]]))
    np.testing.assert_array_equal(s["occ_instance"], d["instance"][i, j, k])
    assert s["occ_flow"].shape == (len(i), 3) and s["occ_mask_camera"].dtype == bool
    assert s["occ_mask_camera"].any() and not s["occ_mask_camera"].all()
    # the grid the rows index
    np.testing.assert_array_equal(s["grid_shape"], d["semantic"].shape)
    np.testing.assert_allclose(s["grid_origin"], GridSpec(voxel_size=0.1).region_min)


def test_crop_faces_on_voxel_centres_take_those_voxels_on_every_axis(default_01):
    from carlaocc.catalog.samples import crop_box

    g = GridSpec(voxel_size=0.2)
    o = np.asarray(g.region_min)
    # faces exactly on centres (index 3 and 6 on each axis)
    lo, hi = crop_box(g, (o + 3.5 * 0.2, o + 6.5 * 0.2))
    assert lo.tolist() == [3, 3, 3] and hi.tolist() == [7, 7, 7]


def test_a_crop_is_the_same_voxels_as_the_sparse_rows_inside_it(default_01, ds):
    crop = ((2.0, -6.0, -2.5), (14.3, 6.0, 1.0))
    c = CarlaOccDataset(default_01.url, occupancy="crop", crop=crop, cameras=False, lidar=False, boxes=False)[1]
    s = ds[1]
    lo = c["crop_offset"]
    size = np.array(c["semantic"].shape)
    centres = s["grid_origin"] + (lo + 0.5) * 0.1
    assert np.all(centres >= crop[0]) and np.all(centres - 0.1 < crop[0])  # the first centre inside
    inside = np.all((s["occ"][:, :3] >= lo) & (s["occ"][:, :3] < lo + size), axis=1)
    rows = s["occ"][inside]
    got = c["semantic"][tuple((rows[:, :3] - lo).T)]
    np.testing.assert_array_equal(got, rows[:, 3])
    assert (c["semantic"] > 0).sum() == inside.sum() > 0
    assert c["flow"].shape == (*size, 3) and c["mask_camera"].dtype == bool


def test_boxes_hold_their_instance_voxels_and_land_on_their_pixels(ds):
    s = ds[1]
    assert len(s["boxes"]) > 0
    occ, inst = s["occ"], s["occ_instance"]
    centres = s["grid_origin"] + (occ[:, :3] + 0.5) * s["voxel_size"]
    checked = 0
    for b, pose, iid in zip(s["boxes"], s["box_pose"], s["box_instance"]):
        np.testing.assert_allclose(pose[:3, 3], b[:3], atol=1e-4)
        mine = centres[inst == iid]
        if not len(mine):
            continue  # outside the grid
        # in the box's own frame every voxel centre of the instance is within the box (+ a voxel)
        local = (mine - pose[:3, 3]) @ pose[:3, :3]
        assert np.all(np.abs(local) <= b[3:6] / 2 + 0.1 * np.sqrt(3)), iid
        # yaw is the box x axis's heading in the LiDAR frame
        assert np.isclose(b[6], np.arctan2(pose[1, 0], pose[0, 0]), atol=1e-5)
        checked += 1
    assert checked >= 1
    # each box centre in front of camera_00 projects onto its own instance's pixels (or, where
    # another object hides it, onto something nearer)
    K, cam_to_lidar = s["cam_intrinsics"][0], s["cam_to_lidar"][0]
    imap, depth_ok = s["cam_instance"][0], 0
    H, W = imap.shape
    for b, iid in zip(s["boxes"], s["box_instance"]):
        p = np.linalg.inv(cam_to_lidar) @ np.append(b[:3], 1.0)
        if p[2] < 1.0:
            continue
        u, v = (K @ p[:3])[:2] / p[2]
        if not (0 <= u < W and 0 <= v < H):
            continue
        patch = imap[max(0, int(v) - 3):int(v) + 4, max(0, int(u) - 3):int(u) + 4]
        depth_ok += int(iid in patch)
    assert depth_ok >= 1


def test_dense_is_refused_when_too_big_and_bad_options_say_why(default_01):
    with pytest.raises(DatasetError, match="dense_limit"):
        CarlaOccDataset(default_01.url, occupancy="dense", dense_limit=1000)
    with pytest.raises(DatasetError, match="voxelized at 0.3 m"):
        CarlaOccDataset(default_01.url, voxel_size=0.3)
    with pytest.raises(DatasetError, match="split='dev'"):
        CarlaOccDataset(default_01.url, split="dev")
    with pytest.raises(DatasetError, match="crop"):
        CarlaOccDataset(default_01.url, occupancy="crop")
    with pytest.raises(DatasetError, match="camera_maps"):
        CarlaOccDataset(default_01.url, camera_maps=("lidar",))
    with pytest.raises(DatasetError, match="voxel_size=-1"):
        CarlaOccDataset(default_01.url, voxel_size=-1)
    with pytest.raises(DatasetError, match="does not exist"):
        CarlaOccDataset(default_01.url + "_nowhere")
    for bad in ((0, 1), ((0, 0, 0), (1, 1)), ((5, 0, 0), (1, 1, 1))):
        with pytest.raises(DatasetError, match="crop="):
            CarlaOccDataset(default_01.url, occupancy="crop", crop=bad)
    with pytest.raises(DatasetError, match="the crop holds"):
        CarlaOccDataset(default_01.url, occupancy="crop", crop=((0, -20, -3), (50, 20, 9)), dense_limit=10**6)
    one = CarlaOccDataset(default_01.url, sequences="town00_high_seq000", cameras=False, lidar=False)  # a str is one id
    assert {s for s, _ in one.samples} == {"town00_high_seq000"}
    with pytest.raises(TypeError):
        one[1.7]
    assert one[np.int64(0)]["frame_index"] == one.samples[0][1]


def test_collate_stacks_same_shapes_and_lists_the_rest(ds):
    batch = collate([ds[0], ds[1]])
    assert batch["images"].shape == (2, 1, 376, 1408, 3) and batch["ego_pose"].shape == (2, 4, 4)
    assert isinstance(batch["occ"], list) and len(batch["occ"]) == 2
    assert batch["sequence_id"] == [ds.samples[0][0], ds.samples[1][0]]
    assert batch["frame_index"].tolist() == [ds.samples[0][1], ds.samples[1][1]]


def test_torch_dataloader_with_two_workers(default_01):
    torch = pytest.importorskip("torch") if not os.environ.get("CI") else __import__("torch")
    # one sequence (two frames): a batch from each worker
    ds = CarlaOccDataset(default_01.url, cameras=False, camera_maps=(), lidar=True, sequences=["town00_high_seq000"])
    loader = torch.utils.data.DataLoader(ds, batch_size=1, num_workers=2, collate_fn=collate,
                                         multiprocessing_context="spawn")
    seen = []
    for batch in loader:
        for k, seq in enumerate(batch["sequence_id"]):
            seen.append((seq, int(batch["frame_index"][k])))
            i = ds.samples.index(seen[-1])
            np.testing.assert_array_equal(batch["occ"][k], ds[i]["occ"])
    assert seen == ds.samples and len(seen) == 2
