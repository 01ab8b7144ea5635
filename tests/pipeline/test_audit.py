"""``carlaocc audit``: s_sc and s_tc of Occ3D, SemanticKITTI, SurroundOcc and CarlaOcc-npz files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from catalog.formats import (Occ3DFrame, SemanticKittiVoxels, dense_to_surroundocc, load_occ3d, save_carlaocc_npz,
                             save_occ3d, save_semantickitti, save_surroundocc, to_raw)
from pipeline.audit import AuditError, audit_command, load_poses
from pipeline.cli import app
from stages.metrics import isolated_mask_reference, spatial_continuity_counts

cli = CliRunner()
OCC3D_SAMPLE = Path("/work/shared/testdata/occupancy/occ3d-nuscenes/labels.npz")


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


@pytest.mark.skipif(not OCC3D_SAMPLE.is_file(), reason="shared Occ3D sample not present")
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


def _poses(shifts, vs):
    out = []
    for s in shifts:
        p = np.eye(4)
        p[0, 3] = s * vs
        out.append(p)
    return np.stack(out)


def _write_kitti_poses(path: Path, poses: np.ndarray) -> Path:
    path.write_text("\n".join(" ".join(f"{v:.9g}" for v in p[:3].ravel()) for p in poses) + "\n")
    return path


SHIFTS = (0, 2, 3)


def test_carlaocc_npz_sequence_s_sc_and_s_tc(tmp_path):
    X, vs, origin = 20, 0.4, (-4.0, -2.0, -1.2)
    world = _world((X + max(SHIFTS), 10, 8), (1, 3, 9))
    frames = []
    for t, s in enumerate(SHIFTS):
        sem = world[s:s + X].astype(np.uint8)
        frames.append(sem)
        save_carlaocc_npz(tmp_path / "seq" / f"{t:04d}.npz", sem, np.zeros_like(sem, np.uint32), vs, origin)
    # a car (dynamic) in frame 1 only: excluded from s_tc, but it counts for s_sc
    car = frames[1].copy()
    car[0, 0, 2] = 14
    save_carlaocc_npz(tmp_path / "seq" / "0001.npz", car, np.zeros_like(car, np.uint32), vs, origin)
    frames[1] = car
    poses = _write_kitti_poses(tmp_path / "poses.txt", _poses(SHIFTS, vs))
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
    still = _write_kitti_poses(tmp_path / "still.txt", _poses((0, 0, 0), vs))
    _run("carlaocc-npz", tmp_path / "seq", "--poses", still, "--json", out)
    assert json.loads(out.read_text())["s_tc"] < 0.9


def test_occ3d_sequence_uses_the_camera_mask(tmp_path):
    shape = (24, 12, 8)
    world = _world((shape[0] + 3, *shape[1:]), (11, 15, 16))
    frames = [np.where(world[s:s + shape[0]] == 0, 17, world[s:s + shape[0]]).astype(np.uint8) for s in (0, 3)]
    frames[1][5, 5, 1] = 13  # frame t+1 calls one ground voxel sidewalk ...
    masks = [np.ones(shape, np.uint8), np.ones(shape, np.uint8)]
    for t in range(2):
        save_occ3d(tmp_path / f"scene/{t}/labels.npz", Occ3DFrame(frames[t], masks[t], masks[t]))
    poses = tmp_path / "poses.npy"
    np.save(poses, _poses((0, 3), 0.4))
    out = tmp_path / "r.json"
    assert _run("occ3d", tmp_path / "scene", "--poses", poses, "--json", out).exit_code == 0
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
    with pytest.raises(AuditError, match="2 poses for 3 frames"):
        from pipeline.audit import FORMATS, audit

        audit(FORMATS["carlaocc-npz"], [tmp_path / "d/a.npz"] * 3, np.stack([np.eye(4)] * 2))
    # a single good frame with poses: no pair, no s_tc value
    result, table = audit_command("carlaocc-npz", [str(tmp_path / "d/a.npz")], str(tmp_path / "one.txt"))
    assert result.s_tc != result.s_tc and "CarlaOcc" in table
