"""`carlaocc export openocc-v2 | uniocc` (and grid.json in every export) on the shared built root
(0.1 m, two frames a sequence), read back by independent readers written from
../shared/reference/training-formats.md sections 2 and 3: keys, shapes, dtypes and ids; the
OpenOcc flow of a moving actor's voxels is its velocity in the ego axes; UniOcc's forward and
backward flows of road voxels are the ego motion between the frames' poses, in voxels."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.sql import query
from carlaocc.data import CarlaOccDataset
from carlaocc.pipeline.cli import app
from carlaocc.schemas import taxonomy

cli = CliRunner()
CENTRES = None


def _export(root, fmt, tmp_path_factory, *extra) -> Path:
    out = tmp_path_factory.mktemp(fmt) / fmt
    r = cli.invoke(app, ["export", fmt, "--res", "0.1", "--root", root.url, "--out", str(out), *extra])
    assert r.exit_code == 0, r.output
    return out


SEQ = "town00_high_seq000"  # the busiest sequence: moving vehicles in every frame


@pytest.fixture(scope="module")
def openocc(openocc_01) -> Path:
    return openocc_01  # SEQ only


@pytest.fixture(scope="module")
def uniocc(default_01, tmp_path_factory) -> Path:
    return _export(default_01, "uniocc", tmp_path_factory, "--sequence", SEQ)


def _centres() -> np.ndarray:
    axes = [(-40.0, -40.0, -1.0)[a] + (np.arange(n) + 0.5) * 0.4 for a, n in enumerate((200, 200, 16))]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def test_openocc_v2_semantics_instances_and_flow(openocc, default_01):
    ds = CarlaOccDataset(default_01.url, occupancy="none", cameras=False, lidar=False, sequences=[SEQ])
    names = taxonomy.OPENOCC_V2_NAMES
    moving_checked = 0
    for k, (seq, frame) in enumerate(ds.samples):
        z = np.load(openocc / seq / f"{seq}_{frame:06d}" / "labels.npz")
        assert sorted(z.files) == ["flow", "instances", "semantics"]
        sem, inst, flow = z["semantics"], z["instances"], z["flow"]
        assert sem.shape == inst.shape == (200, 200, 16) and flow.shape == (200, 200, 16, 2)
        assert sem.dtype == np.uint8 and flow.dtype == np.float32 and sem.max() <= 16
        assert (sem == 16).any() and (sem == names.index("driveable_surface")).any()
        # instances sit on road-user classes only; stuff and free carry none
        things = {names.index(n) for n in ("car", "truck", "bus", "trailer", "bicycle", "motorcycle", "pedestrian")}
        assert set(np.unique(sem[inst > 0]).tolist()) <= things | {names.index("manmade")}
        assert not inst[sem == 16].any() and not flow[sem == 16].any()
        s = ds[k]
        R = s["lidar_to_ego"][:3, :3]
        vehicles = {taxonomy.by_name(n).id for n in ("Car", "Truck", "Bus")}  # rigid (a walker's limbs swing)
        for iid, v, c in zip(s["box_instance"], s["box_velocity"], s["box_semantic"]):
            sel = inst == iid
            if int(c) not in vehicles or np.linalg.norm(v) < 0.5 or sel.sum() < 5:
                continue
            want = (R @ v)[:2]
            got = np.median(flow[sel], axis=0)
            assert np.allclose(got, want, atol=0.15 * np.linalg.norm(want) + 0.05), (seq, frame, iid, got, want)
            moving_checked += 1
    assert moving_checked >= 2
    grid = json.loads((openocc / "grid.json").read_text())
    assert grid["labels"] == list(names) and grid["free_label"] == 16 and grid["voxel_size"] == 0.4


def test_uniocc_layout_and_flows_follow_the_poses(uniocc, default_01):
    infos = pickle.load(open(uniocc / "scene_infos.pkl", "rb"))
    assert [i["scene_name"] for i in infos] == [SEQ]
    centres = _centres()
    road = taxonomy.UNIOCC_NAMES.index("road")
    for info in infos:
        seq = info["scene_name"]
        rows = query(default_01, f"SELECT frame_index, timestamp, ego_pose FROM frames WHERE sequence_id = '{seq}' "
                                 "ORDER BY 1")[1]
        poses = {f: np.asarray(p, float).reshape(4, 4) for f, _, p in rows}
        assert len(info["occ_in_scene_paths"]) == len(rows)
        for t, rel in enumerate(info["occ_in_scene_paths"]):
            z = np.load(uniocc / rel, allow_pickle=True)
            for key in ("occ_label", "occ_mask_camera", "occ_flow_forward", "occ_flow_backward",
                        "ego_to_world_transformation", "cameras", "annotations"):
                assert key in z.files, key
            lab, fwd, bwd = z["occ_label"], z["occ_flow_forward"], z["occ_flow_backward"]
            assert lab.shape == (200, 200, 16) and lab.max() <= 10 and fwd.shape == bwd.shape == (200, 200, 16, 3)
            np.testing.assert_allclose(z["ego_to_world_transformation"], poses[t])
            assert not fwd[lab == 10].any()  # free voxels carry no flow
            if t == len(rows) - 1:
                assert not fwd.any()
            if t == 0:
                assert not bwd.any()
            # road voxels are static: their flow is the ego motion, in voxels of the current grid
            sel = lab == road
            p = centres[sel]
            for other, flow in ((t + 1, fwd), (t - 1, bwd)):
                if other not in poses:
                    continue
                M = np.linalg.inv(poses[other]) @ poses[t]
                q = p @ M[:3, :3].T + M[:3, 3]
                np.testing.assert_allclose(flow[sel], (q - p) / 0.4, atol=1e-3)
            cams = list(z["cameras"])
            assert cams and cams[0]["filename"].startswith("samples/") and np.asarray(cams[0]["intrinsics"]).shape == (3, 3)
            for a in z["annotations"]:
                np.testing.assert_allclose(poses[t] @ a["agent_to_ego"], a["agent_to_world"], atol=1e-6)
                assert 0 <= a["category_id"] <= 9 and len(a["size"]) == 3


def test_every_export_writes_its_grid(default_01, tmp_path_factory):
    for fmt, origin, size in (("occ3d", [-40.0, -40.0, -1.0], 0.4), ("surroundocc", [-50.0, -50.0, -5.0], 0.5),
                              ("carlaocc-npz", [-25.6, -25.6, -3.0], 0.1)):
        out = _export(default_01, fmt, tmp_path_factory, "--sequence", SEQ)
        grid = json.loads((out / "grid.json").read_text())
        assert grid["origin"] == origin and grid["voxel_size"] == size, fmt
        assert grid["index_to_metre"] == "centre = origin + (index + 0.5) * voxel_size"
        assert grid["axis_order"] == ["x", "y", "z"] and grid["built_from_label_table"] == "release"


def test_sscbench_kitti360_targets(default_01, tmp_path_factory):
    """MonoScene-style: preprocess/labels/<seq>/<frame>_1_1.npy (256, 256, 32) learning ids with
    unobserved 255, _1_8.npy its 8x reduction (checked against a brute-force block loop), and the
    first camera as image_00."""
    from PIL import Image

    seq = SEQ
    out = _export(default_01, "sscbench-kitti360", tmp_path_factory, "--sequence", seq)
    full = np.load(out / "preprocess" / "labels" / seq / "000001_1_1.npy")
    small = np.load(out / "preprocess" / "labels" / seq / "000001_1_8.npy")
    assert full.shape == (256, 256, 32) and full.dtype == np.uint8 and small.shape == (32, 32, 4)
    values = set(np.unique(full).tolist())
    assert values <= set(range(19)) | {255} and 255 in values and 0 in values and len(values - {0, 255}) >= 3
    road = taxonomy.SSCBENCH_KITTI360_NAMES.index("road")
    assert (full == road).any()
    for x in range(32):
        for y in range(32):
            for z in range(4):
                b = full[x * 8:(x + 1) * 8, y * 8:(y + 1) * 8, z * 8:(z + 1) * 8].ravel()
                n0, n255 = int((b == 0).sum()), int((b == 255).sum())
                if n0 + n255 > 0.95 * 512:
                    want = 0 if n0 > n255 else 255
                else:
                    want = int(np.argmax(np.bincount(b[(b > 0) & (b < 255)])))
                assert small[x, y, z] == want, (x, y, z)
    img = Image.open(out / "data_2d_raw" / seq / "image_00" / "data_rect" / "000001.png")
    assert img.size == (1408, 376) and img.mode == "RGB"
    grid = json.loads((out / "grid.json").read_text())
    assert grid["origin"] == [0.0, -25.6, -2.0] and grid["shape"] == [256, 256, 32] and grid["free_label"] == 0
