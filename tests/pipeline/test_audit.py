"""``carlaocc audit``: s_sc and s_tc of Occ3D, SemanticKITTI, SurroundOcc and CarlaOcc-npz files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.formats import (FORMATS, DatasetInputError, Occ3DFrame, SemanticKittiVoxels, dense_to_surroundocc,
                                      load_occ3d, save_carlaocc_npz, save_occ3d, save_semantickitti, save_surroundocc,
                                      to_raw)  # fmt: skip
from carlaocc.catalog.formats.layout import collect_inputs
from carlaocc.catalog.formats.poses import KeyedPoses, load_poses, plan_sequences
from carlaocc.pipeline.commands.audit import audit_command
from carlaocc.pipeline.cli import app
from carlaocc.stages.quality import isolated_mask_reference, spatial_continuity_counts
from shared_data import needs, shared_path

cli = CliRunner()
OCC3D_SAMPLE = shared_path("occupancy/occ3d-nuscenes/labels.npz")


def _run(*args):
    return cli.invoke(app, ["audit", *map(str, args)])


def _isolated_per_class(sem: np.ndarray, classes) -> tuple[int, int]:
    """Independent s_sc terms: per class, voxels with no face neighbour of the same class."""
    occupied = isolated = 0
    for c in classes:
        m = sem == c
        p = np.pad(m, 1)
        nb = (p[:-2, 1:-1, 1:-1] | p[2:, 1:-1, 1:-1] | p[1:-1, :-2, 1:-1] | p[1:-1, 2:, 1:-1]
              | p[1:-1, 1:-1, :-2] | p[1:-1, 1:-1, 2:])
        occupied += int(m.sum())
        isolated += int((m & ~nb).sum())
    return occupied, isolated


@needs(OCC3D_SAMPLE)
def test_real_occ3d_sample(tmp_path):
    out = tmp_path / "occ3d.json"
    r = _run("occ3d", OCC3D_SAMPLE.parent, "--json", out, "--per-frame")
    assert r.exit_code == 0, r.output
    assert "Occ3D-nuScenes" in r.output
    report = json.loads(out.read_text())
    sem = load_occ3d(OCC3D_SAMPLE).semantics
    # independently: Occ3D ids 0..16 are classes, 17 is free
    occupied, isolated = _isolated_per_class(sem, range(17))
    assert (report["occupied"], report["isolated"]) == (occupied, isolated)
    assert report["frames"] == 1 and report["s_sc"] == pytest.approx(1 - isolated / occupied, abs=0)
    # and through the kernel and its brute-force reference on the remapped grid (free -> 0)
    internal = np.where(sem == 17, 0, sem + 1).astype(np.uint8)
    assert int(isolated_mask_reference(internal).sum()) == isolated
    assert spatial_continuity_counts(internal).score == report["s_sc"]
    assert report["s_tc"] is None and report["per_frame"][0]["s_sc"] == report["s_sc"]
    names = {c["name"]: c for c in report["per_class"]}
    assert "free" not in names and names["vegetation"]["occupied"] == int((sem == 16).sum())


# -- synthetic sequences: a static street seen from a sensor moving by whole voxels --------------
def _world(shape, labels, seed=0):
    """A static world ``shape`` (x long enough for the moves): ground, a block, sparse bushes.
    ``labels``: dataset ids (ground, block, bush)."""
    rng = np.random.default_rng(seed)
    ground, block, bush = labels
    w = np.zeros(shape, np.int64)
    w[:, :, 1] = ground
    w[6:12, 2:8, 2:6] = block
    idx = rng.integers(0, [shape[0], shape[1], shape[2]], size=(40, 3))
    idx[:, 2] = np.maximum(idx[:, 2], 2)
    w[tuple(idx.T)] = np.where(w[tuple(idx.T)] == 0, bush, w[tuple(idx.T)])
    return w


def _poses(shifts, voxel_size):
    out = []
    for s in shifts:
        p = np.eye(4)
        p[0, 3] = s * voxel_size
        out.append(p)
    return np.stack(out)


def _write_kitti_poses(path: Path, poses: np.ndarray) -> Path:
    path.write_text("\n".join(" ".join(f"{v:.9g}" for v in p[:3].ravel()) for p in poses) + "\n")
    return path


SHIFTS = (0, 2, 3)


def test_carlaocc_npz_sequence_s_sc_and_s_tc(tmp_path):
    X, voxel_size, origin = 20, 0.4, (-4.0, -2.0, -1.2)
    world = _world((X + max(SHIFTS), 10, 8), (1, 3, 9))
    frames = []
    for t, s in enumerate(SHIFTS):
        sem = world[s:s + X].astype(np.uint8)
        frames.append(sem)
        save_carlaocc_npz(tmp_path / "seq" / f"{t:04d}.npz", sem, np.zeros_like(sem, np.uint32), voxel_size, origin)
    # a car (dynamic) in frame 1 only: excluded from s_tc, but it counts for s_sc
    car = frames[1].copy()
    car[0, 0, 2] = 14
    save_carlaocc_npz(tmp_path / "seq" / "0001.npz", car, np.zeros_like(car, np.uint32), voxel_size, origin)
    frames[1] = car
    poses = _write_kitti_poses(tmp_path / "poses.txt", _poses(SHIFTS, voxel_size))
    out = tmp_path / "r.json"
    r = _run("carlaocc-npz", tmp_path / "seq", "--poses", poses, "--json", out)
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    total = sum(_isolated_per_class(f, range(1, 30))[0] for f in frames)
    iso = sum(_isolated_per_class(f, range(1, 30))[1] for f in frames)
    assert (report["occupied"], report["isolated"]) == (total, iso)
    assert report["s_tc"] == 1.0 and [p["s_tc"] for p in report["per_pair"]] == [1.0, 1.0]
    assert report["union"] > 0 and "Car" not in {c["name"] for c in report["per_class"] if c.get("union")}
    assert "CarlaOcc" in r.output and "1.0000" in r.output
    # wrong poses (standing still) make the moved street inconsistent
    still = _write_kitti_poses(tmp_path / "still.txt", _poses((0, 0, 0), voxel_size))
    _run("carlaocc-npz", tmp_path / "seq", "--poses", still, "--json", out)
    assert json.loads(out.read_text())["s_tc"] < 0.9


def _keyed_json(path: Path, frames, poses) -> Path:
    path.write_text(json.dumps([{"frame": f, "pose": p.tolist()} for f, p in zip(frames, poses)]))
    return path


def test_occ3d_sequence_uses_the_camera_mask(tmp_path):
    shape = (200, 200, 16)
    world = _world((shape[0] + 3, *shape[1:]), (11, 15, 16))
    frames = [np.where(world[s:s + shape[0]] == 0, 17, world[s:s + shape[0]]).astype(np.uint8) for s in (0, 3)]
    frames[1][5, 5, 1] = 13  # frame t+1 calls one ground voxel sidewalk ...
    masks = [np.ones(shape, np.uint8), np.ones(shape, np.uint8)]
    for t in range(2):
        save_occ3d(tmp_path / f"scene/{t}/labels.npz", Occ3DFrame(frames[t], masks[t], masks[t]))
    poses = _keyed_json(tmp_path / "poses.json", ["0", "1"], _poses((0, 3), 0.4))
    out = tmp_path / "r.json"
    r = _run("occ3d", tmp_path / "scene", "--poses", poses, "--json", out)
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    ground = int((frames[0][3:, :, 1] == 11).sum())  # ground voxels of frame t that stay in view
    # driveable_surface: I = ground - 1, U = ground; sidewalk: I = 0, U = 1; everything else agrees
    by_name = {c["name"]: c for c in report["per_class"]}
    assert (by_name["driveable_surface"]["intersection"], by_name["driveable_surface"]["union"]) == (ground - 1, ground)
    assert (by_name["sidewalk"]["intersection"], by_name["sidewalk"]["union"]) == (0, 1)
    assert report["union"] - report["intersection"] == 2
    # ... where its cameras did not look: the mask removes the disagreement
    masks[1][5, 5, 1] = 0
    save_occ3d(tmp_path / "scene/1/labels.npz", Occ3DFrame(frames[1], masks[1], masks[1]))
    assert _run("occ3d", tmp_path / "scene", "--poses", poses, "--json", out).exit_code == 0
    assert json.loads(out.read_text())["s_tc"] == 1.0


def test_semantickitti_labels_invalid_mask_and_calib(tmp_path):
    shape = (256, 256, 32)
    world = _world((shape[0] + 2, *shape[1:]), (9, 13, 15))  # road, building, vegetation (learning ids)
    d = tmp_path / "sequences" / "00"
    invalid = []
    for t, s in enumerate((0, 2)):
        learning = world[s:s + shape[0]].astype(np.uint8)
        inv = np.zeros(shape, bool)
        if t == 1:
            learning[40, 40, 1] = 11  # sidewalk where frame 0 sees road ...
            inv[40, 40, 1] = True  # ... in a voxel that is invalid in frame 1
        invalid.append(inv)
        save_semantickitti(d / "voxels", f"{t:06d}", SemanticKittiVoxels(
            occupied=learning > 0, invalid=inv, occluded=np.zeros(shape, bool), labels=to_raw(learning)))
    (d / "labels").mkdir()
    (d / "labels" / "000000.label").write_bytes(b"\0" * 16)  # point labels: not a voxel scan
    # KITTI poses.txt holds camera-0 poses; calib's Tr maps velodyne to camera 0
    tr = np.array([[0, -1, 0, 0.1], [0, 0, -1, -0.05], [1, 0, 0, -0.3], [0, 0, 0, 1]], float)
    velo = _poses((0, 2), 0.2)
    cam = tr @ velo @ np.linalg.inv(tr)
    poses = _write_kitti_poses(tmp_path / "poses.txt", cam)
    calib = tmp_path / "calib.txt"
    calib.write_text("P0: " + " ".join(["0"] * 12) + "\nTr: " + " ".join(f"{v:.12g}" for v in tr[:3].ravel()) + "\n")
    out = tmp_path / "r.json"
    r = _run("semantickitti", d, "--poses", poses, "--calib", calib, "--json", out)
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert report["frames"] == 2 and report["s_tc"] == 1.0
    # without the calibration the camera poses move the grid the wrong way
    _run("semantickitti", d, "--poses", poses, "--json", out)
    assert json.loads(out.read_text())["s_tc"] < 0.9


def test_surroundocc_rows_and_noise_label(tmp_path):
    shape = (200, 200, 16)
    world = _world((shape[0] + 1, *shape[1:]), (11, 15, 16))
    dense = world[:shape[0]].copy()
    dense[0, 0, 9:12] = 0
    dense[0, 0, 10] = 200  # a lone "noise" voxel (SurroundOcc label 0): occupied, its own class
    rows = dense_to_surroundocc(np.where(dense == 0, 255, dense), free=255)
    rows[rows[:, 3] == 200, 3] = 0
    dense[0, 0, 10] = 0
    save_surroundocc(tmp_path / "a.npy", rows)
    out = tmp_path / "r.json"
    assert _run("surroundocc", tmp_path / "a.npy", "--json", out).exit_code == 0
    report = json.loads(out.read_text())
    by_name = {c["name"]: c for c in report["per_class"]}
    assert by_name["noise"] == {"id": 0, "name": "noise", "occupied": 1, "isolated": 1, "s_sc": 0.0}
    occ, iso = _isolated_per_class(dense, (11, 15, 16))
    assert (report["occupied"], report["isolated"]) == (occ + 1, iso + 1)


def test_pose_files_agree(tmp_path):
    poses = _poses((0, 1, 5), 0.4)
    poses[1, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    np.save(tmp_path / "p.npy", poses)
    (tmp_path / "p.json").write_text(json.dumps({"poses": poses.tolist()}))
    (tmp_path / "p16.txt").write_text("# x\n\n" + "\n".join(" ".join(map(str, p.ravel())) for p in poses))
    _write_kitti_poses(tmp_path / "p12.txt", poses)
    for name in ("p.npy", "p.json", "p16.txt", "p12.txt"):
        assert np.allclose(load_poses(tmp_path / name), poses), name


def test_clear_errors(tmp_path):
    sem = np.zeros((4, 4, 4), np.uint8)
    sem[0, 0, 0] = 1
    save_carlaocc_npz(tmp_path / "d/a.npz", sem, np.zeros_like(sem, np.uint32), 0.5, (0, 0, 0))
    save_carlaocc_npz(tmp_path / "d/b.npz", sem, np.zeros_like(sem, np.uint32), 0.5, (0, 0, 0))
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad/x.npz").write_bytes(b"not a zip")
    (tmp_path / "one.txt").write_text(" ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]))
    (tmp_path / "short.txt").write_text("1 2 3\n")
    cases = [
        (["nusc", tmp_path / "d"], "unknown format 'nusc'; choose one of occ3d"),
        (["occ3d", tmp_path / "d"], "no occ3d files (*labels.npz) under"),
        (["carlaocc-npz", tmp_path / "nothing"], "no such file or directory"),
        (["carlaocc-npz", tmp_path / "bad"], "x.npz"),
        (["carlaocc-npz", tmp_path / "d", "--poses", tmp_path / "one.txt"], "1 poses for 2 carlaocc-npz frames"),
        (["carlaocc-npz", tmp_path / "d", "--poses", tmp_path / "short.txt"], "short.txt:1: a pose is 12"),
        (["carlaocc-npz", tmp_path / "d", "--calib", tmp_path / "one.txt"], "--calib converts --poses"),
    ]
    for args, message in cases:
        r = _run(*args)
        assert r.exit_code == 2, (args, r.output)
        assert message in r.output and r.output.startswith("error: "), (args, r.output)
    npz = FORMATS["carlaocc-npz"]
    inputs = collect_inputs(npz, [tmp_path / "d", tmp_path / "d/a.npz"])  # a file found twice is one frame
    assert [i.path.name for i in inputs] == ["a.npz", "b.npz"]
    with pytest.raises(DatasetInputError, match="3 poses for fewer carlaocc-npz frames, and a.npz has no frame number"):
        plan_sequences(npz, inputs, np.stack([np.eye(4)] * 3))
    # a file of a SemanticKITTI scan named once, not twice ("x.label: x.invalid: ...")
    save_semantickitti(tmp_path / "sk", "000000", SemanticKittiVoxels(*(np.zeros((256, 256, 32), bool),) * 3,
                                                                       labels=np.zeros((256, 256, 32), np.uint16)))
    (tmp_path / "sk/000000.invalid").write_bytes(b"\0" * 100)
    r = _run("semantickitti", tmp_path / "sk")
    assert r.exit_code == 2 and r.output.startswith(f"error: {tmp_path / 'sk/000000.invalid'}: truncated"), r.output
    # a single good frame with poses: no pair, no s_tc value
    result, table = audit_command("carlaocc-npz", [str(tmp_path / "d/a.npz")], str(tmp_path / "one.txt"))
    assert result.s_tc != result.s_tc and "CarlaOcc" in table


# -- sequences: pairs stay inside one sequence, in time order ------------------------------------
def _occ3d_frame(world, s, X=200):
    return np.where(world[s:s + X] == 0, 17, world[s:s + X]).astype(np.uint8)


def test_occ3d_scenes_and_keyed_poses_give_the_time_order(tmp_path):
    """Two scenes of one static world, the sensor moving by whole voxels; sample tokens whose path
    order is not the time order. Only the keyed poses' order, within each scene, gives s_tc = 1."""
    ones = np.ones((200, 200, 16), np.uint8)
    # scene-a: time order 0 -> 1 -> 2 is tokens f3 -> 0b -> 9c (path order 0b, 9c, f3)
    scene_a = {"f3": 0, "0b": 2, "9c": 5}
    # scene-b is another place (other classes) in its own world frame: paired with scene-a's last
    # frame it would disagree everywhere
    scene_b = {"77": 6, "1e": 4, "c5": 1}
    for scene, frames, labels in (("scene-a", scene_a, (11, 15, 16)), ("scene-b", scene_b, (13, 1, 14))):
        world = _world((206, 200, 16), labels, seed=3)
        for token, s in frames.items():
            save_occ3d(tmp_path / "gts" / scene / token / "labels.npz", Occ3DFrame(_occ3d_frame(world, s), ones, ones))
    voxel_size = 0.4
    # scene-b's c5 has no pose: left out of s_tc; scene-a's last frame is named by its relative path
    keys = ["f3", "0b", "scene-a/9c/labels.npz", "77", "1e", "not-audited"]
    shifts = [0, 2, 5, 6, 4, 0]
    poses = _keyed_json(tmp_path / "poses.json", keys, _poses(shifts, voxel_size))
    out = tmp_path / "r.json"
    r = _run("occ3d", tmp_path / "gts", "--poses", poses, "--json", out, "--per-frame")
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert report["s_tc"] == 1.0 and report["union"] > 0
    assert (report["frames"], report["sequences"], report["pairs"]) == (6, 2, 3)
    assert (report["frames_without_pose"], report["poses_unmatched"]) == (1, 1)
    paths = [Path(f["path"]).parent.name for f in report["per_frame"]]
    assert paths == ["f3", "0b", "9c", "77", "1e", "c5"]  # time order, the frame without a pose last
    assert [(p["t"], p["t1"]) for p in report["per_pair"]] == [(0, 1), (1, 2), (3, 4)]
    assert "1 frame(s) without a pose left out" in r.output
    # the time-ordered poses given to the frames in path order (as the per-listed-frame form would)
    wrong = _keyed_json(tmp_path / "wrong.json", ["0b", "9c", "f3", "1e", "77"], _poses(shifts[:5], voxel_size))
    assert _run("occ3d", tmp_path / "gts", "--poses", wrong, "--json", out).exit_code == 0
    assert json.loads(out.read_text())["s_tc"] < 1.0
    # one pose per listed frame cannot order occ3d frames
    np.save(tmp_path / "p.npy", _poses([0] * 6, voxel_size))
    r = _run("occ3d", tmp_path / "gts", "--poses", tmp_path / "p.npy")
    assert r.exit_code == 2 and "occ3d paths carry no time order" in r.output and "\"frame\"" in r.output
    # a keyed file naming nothing audited
    r = _run("occ3d", tmp_path / "gts", "--poses", _keyed_json(tmp_path / "none.json", ["x"], _poses([0], voxel_size)))
    assert r.exit_code == 2 and "none of its 1 frames names an audited occ3d file" in r.output


def test_numbered_files_sort_numerically_within_each_directory(tmp_path):
    """carlaocc-npz files 0, 2, 10 (path order 0, 10, 2) in two directories: one pose per listed
    frame, listed directory by directory in frame-number order; no pair crosses directories."""
    X, voxel_size, origin = 20, 0.4, (-4.0, -2.0, -1.2)
    world = _world((X + 9, 10, 8), (1, 3, 9), seed=5)
    shifts = {"a": {0: 0, 2: 2, 10: 3}, "b": {1: 9, 3: 7}}
    listed = []
    for d, frames in shifts.items():
        for n, s in frames.items():
            sem = world[s:s + X].astype(np.uint8)
            save_carlaocc_npz(tmp_path / d / f"{n}.npz", sem, np.zeros_like(sem, np.uint32), voxel_size, origin)
            listed.append(s)
    out = tmp_path / "r.json"
    poses = _write_kitti_poses(tmp_path / "poses.txt", _poses(listed, voxel_size))
    r = _run("carlaocc-npz", tmp_path / "a", tmp_path / "b", "--poses", poses, "--json", out)
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert [Path(f["path"]).name for f in report["per_frame"]] == ["0.npz", "2.npz", "10.npz", "1.npz", "3.npz"]
    assert report["s_tc"] == 1.0 and [(p["t"], p["t1"]) for p in report["per_pair"]] == [(0, 1), (1, 2), (3, 4)]


def test_semantickitti_pose_per_scan_is_picked_by_frame_number(tmp_path):
    """KITTI poses.txt has a pose per LiDAR scan; SemanticKITTI voxels exist for every 5th scan."""
    shape = (256, 256, 32)
    world = _world((shape[0] + 10, *shape[1:]), (9, 13, 15), seed=7)
    voxels = tmp_path / "sequences" / "08" / "voxels"
    for scan in (0, 5, 10):  # the sensor moves one voxel per scan
        learning = world[scan:scan + shape[0]].astype(np.uint8)
        save_semantickitti(voxels, f"{scan:06d}", SemanticKittiVoxels(
            occupied=learning > 0, invalid=np.zeros(shape, bool), occluded=np.zeros(shape, bool),
            labels=to_raw(learning)))
    tr = np.array([[0, -1, 0, 0.1], [0, 0, -1, -0.05], [1, 0, 0, -0.3], [0, 0, 0, 1]], float)
    velo = _poses(range(13), 0.2)  # scans 0..12
    poses = _write_kitti_poses(tmp_path / "poses.txt", tr @ velo @ np.linalg.inv(tr))
    calib = tmp_path / "calib.txt"
    calib.write_text("Tr: " + " ".join(f"{v:.12g}" for v in tr[:3].ravel()) + "\n")
    out = tmp_path / "r.json"
    r = _run("semantickitti", voxels, "--poses", poses, "--calib", calib, "--json", out)
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert report["frames"] == 3 and report["pairs"] == 2 and report["s_tc"] == 1.0
    # a poses.txt too short for the last voxel scan
    short = _write_kitti_poses(tmp_path / "short.txt", velo[:8])
    r = _run("semantickitti", voxels, "--poses", short, "--calib", calib)
    assert r.exit_code == 2 and "none for frame 10" in r.output and "every 5th scan" in r.output
    # two sequences: a per-scan list is ambiguous
    other = tmp_path / "sequences" / "09" / "voxels"
    for f in voxels.iterdir():
        (other / f.name).parent.mkdir(parents=True, exist_ok=True)
        (other / f.name).write_bytes(f.read_bytes())
    r = _run("semantickitti", voxels, other, "--poses", poses)
    assert r.exit_code == 2 and "13 poses for 6 semantickitti frames" in r.output and "keyed" in r.output


def test_occ3d_other_grids_and_ids_are_refused(tmp_path):
    small = np.full((10, 10, 16), 17, np.uint8)
    save_occ3d(tmp_path / "s/t/labels.npz", Occ3DFrame(small, small * 0, small * 0))
    r = _run("occ3d", tmp_path / "s")
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert r.output.startswith(f"error: {tmp_path / 's/t/labels.npz'}: Occ3D-nuScenes grids are (200, 200, 16)")
    sem = np.full((200, 200, 16), 17, np.uint8)
    sem[1, 2, 3] = 18
    save_occ3d(tmp_path / "i/t/labels.npz", Occ3DFrame(sem, sem * 0, sem * 0))
    r = _run("occ3d", tmp_path / "i")
    assert r.exit_code == 2 and "labels.npz: Occ3D-nuScenes ids are 0..17 (17 = free), found 18" in r.output


def test_keyed_poses_file(tmp_path):
    poses = _poses((0, 1), 0.4)
    p = _keyed_json(tmp_path / "k.json", ["a", "b/c.npz"], poses)
    keyed = load_poses(p)
    assert isinstance(keyed, KeyedPoses) and keyed.frames == ("a", "b/c.npz") and np.allclose(keyed.poses, poses)
    (tmp_path / "flat.json").write_text(json.dumps({"poses": [{"frame": "a", "pose": poses[1][:3].ravel().tolist()}]}))
    assert np.allclose(load_poses(tmp_path / "flat.json").poses, poses[1:])
    for bad, message in (([{"frame": "a"}], "entry 0 must be"), ([{"frame": 3, "pose": poses[0].tolist()}], "a string"),
                         ([{"frame": "a", "pose": [1, 2]}], "entry 0 (a): a pose is"),
                         ([{"frame": "a", "pose": poses[0].tolist()}] * 2, "'a' is listed more than once")):
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        with pytest.raises(DatasetInputError, match=message.replace("(", r"\(").replace(")", r"\)")):
            load_poses(tmp_path / "bad.json")
