"""`carlaocc export carlaocc-release` end to end: the embedded default at 0.1 m (2 frames a
sequence), exported and read back by an independent reader written here from the release's
documentation (docs/source/occ_generation.rst, tutorials/dataset.py, utils/load_utils.py of
fengyi233/carlaocc); the label table recorded with the dataset; splits; a slice by --sequences."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec

cli = CliRunner()
FRAMES = 2  # the built root's frames a sequence (tests/pipeline/conftest.py)


@pytest.fixture(scope="module")
def config_file(default_01_config) -> str:
    return default_01_config


@pytest.fixture(scope="module")
def built(default_01) -> Store:
    return default_01


@pytest.fixture(scope="module")
def exported(release_01) -> Path:
    return release_01


# -- an independent reader of the release layout ------------------------------------------------


def read_split(out: Path, split: str) -> list[tuple[str, int]]:
    """tutorials/dataset.py: '<town> <seq> <frame>' per line, town 10 read as Town10HD_Opt."""
    rows = []
    for line in (out / "splits" / f"{split}.txt").read_text().splitlines():
        town, seq, frame = line.split()
        prefix = "Town10HD_Opt" if town == "10" else f"Town{town}_Opt"
        rows.append((f"{prefix}_Seq{seq}", int(frame)))
    return rows


def read_occupancy(path: Path, decimal: bool = False) -> tuple[np.ndarray, np.ndarray, dict]:
    """utils/load_utils.py load_pano_occ: sparse [x, y, z, label] rows densified by volume_size
    (occ_sparse2dense), then decode_combined_id: semantic = label >> 11 & 0x1F, instance =
    label & 0x7FF. ``decimal``: the documentation's label // 1000, label % 1000."""
    z = np.load(path)
    occ = z["occupancy"]
    dense = np.zeros(tuple(int(v) for v in z["volume_size"]), occ.dtype)
    dense[occ[:, 0], occ[:, 1], occ[:, 2]] = occ[:, 3]
    meta = {"voxel_size": float(z["voxel_size"]), "voxel_origin": np.asarray(z["voxel_origin"], float),
            "volume_size": tuple(int(v) for v in z["volume_size"]), "keys": sorted(z.files)}
    if decimal:
        return dense.astype(np.int64) // 1000, dense.astype(np.int64) % 1000, meta
    return (dense >> 11) & 0x1F, dense & 0x7FF, meta


# utils/labels.py sem_z_order of the release (class -> rank, higher wins a coarse voxel)
Z_ORDER = {0: 0, 23: 1, 10: 2, 25: 3, 1: 4, 24: 5, 2: 6, 27: 7, 29: 8, 5: 9, 28: 10, 4: 11, 3: 12, 26: 13, 6: 14,
           7: 15, 8: 16, 20: 17, 21: 18, 22: 19, 9: 20, 12: 21, 13: 22, 19: 23, 18: 24, 14: 25, 15: 26, 16: 27, 17: 28,
           11: 29}


def test_layout_splits_poses_and_calib(built, exported):
    note = json.loads((exported / "carlaocc_export.json").read_text())
    assert note["label_table"] == "release" and note["encoding"] == "bits"
    assert note["labels"] == "semantic << 11 | instance"
    seqs = {s: v["folder"] for s, v in note["sequences"].items()}
    assert len(seqs) == 3 and all(v["frames"] == FRAMES and v["rate_hz"] == 20.0 for v in note["sequences"].values())
    # every frame of every sequence in exactly one split, and the dataset's splits followed
    lines = {s: read_split(exported, s) for s in ("train", "val", "test")}
    every = [x for v in lines.values() for x in v]
    assert len(every) == len(set(every)) == 3 * FRAMES
    ours = {s: (built.read_bytes(f"splits/{s}.txt").decode().split()) for s in ("train", "val", "test")}
    for split, rows in lines.items():
        assert {folder for folder, _ in rows} == {seqs[s] for s in ours[split]}
    for folder, frame in every:
        d = exported / folder
        # poses/lidar.txt as the reader loads it: frame id then a 4x4
        poses = {int(r[0]): r[1:].reshape(4, 4) for r in np.loadtxt(d / "poses" / "lidar.txt", ndmin=2)}
        assert set(poses) == set(range(FRAMES)) and np.allclose(poses[frame][3], [0, 0, 0, 1])
        for grid in ("vs_0_1", "vs_0_2_forward_view", "vs_0_4_surround_view"):
            assert (d / "occupancy" / grid / f"{frame:04d}.npz").is_file()
    # the poses are ours
    seq = sorted(seqs)[0]
    rows = query(built, f"SELECT frame_index, lidar_pose FROM frames WHERE sequence_id = '{seq}' ORDER BY 1")[1]
    got = np.loadtxt(exported / seqs[seq] / "poses" / "lidar.txt", ndmin=2)
    assert np.allclose(got[:, 1:], np.array([r[1] for r in rows]), atol=1e-6)
    # calib.yaml as utils/load_utils.py reads it
    calib = yaml.safe_load((exported / "calib" / "calib.yaml").read_text())
    cam = calib["cam_settings"]
    assert (cam["width"], cam["height"]) == (1408, 376) and abs(cam["fov"] - 103.744808) < 1e-5
    assert sorted(calib["sensors"]) == [f"cam_{i:02d}" for i in range(6)]
    T = np.array(calib["sensors"]["cam_02"]["transform"])  # left camera: 0.46 m left, looking left
    assert np.allclose(T[:3, 3], [0.0, 0.46, 1.55 - 1.73], atol=1e-6) and np.allclose(T[:3, 0], [0, 1, 0], atol=1e-6)


def test_occupancy_reads_back_the_same_voxels(built, exported):
    note = json.loads((exported / "carlaocc_export.json").read_text())
    occ = OccupancyStore(built)
    grid = GridSpec(voxel_size=0.1)
    rank = np.array([Z_ORDER[c] for c in range(30)])
    for seq, info in note["sequences"].items():
        folder = info["folder"]
        back = {tuple(int(v) for v in k.split(":")): v for k, v in note["instances"][seq].items()}
        for t in range(FRAMES):
            d = occ.read_frame(seq, grid, t, ("semantic", "instance"))
            sem, inst, meta = read_occupancy(exported / folder / "occupancy" / "vs_0_1" / f"{t:04d}.npz")
            # vs_0_1 is our 0.1 m grid voxel for voxel, with exactly the release's keys
            assert meta["keys"] == ["occupancy", "volume_size", "voxel_origin", "voxel_size"]
            assert meta["volume_size"] == (768, 512, 130) and meta["voxel_size"] == 0.1
            assert np.allclose(meta["voxel_origin"], (-25.6, -25.6, -3.0))
            assert np.array_equal(sem, d["semantic"])
            # every thing voxel carries its object's exported id (class-wise), stuff 0
            nz = d["instance"] != 0
            want = np.array([back[(int(s), int(i))] for s, i in zip(d["semantic"][nz], d["instance"][nz])])
            assert np.array_equal(inst[nz], want) and not inst[~nz].any()
            # under the release's table poles, lights and signs are instances, buildings are not
            assert not nz[d["semantic"] == taxonomy.by_name("Building").id].any()
            # ids stay unique per class: two objects never share (class, id)
            pairs = {(int(s), int(i)) for s, i in zip(d["semantic"][nz], d["instance"][nz])}
            assert len({(s, back[(s, i)]) for s, i in pairs}) == len(pairs)
            # the coarser grids: each voxel keeps the class of highest sem_z_order among the fine voxels
            # under it (the release's resampling), and an exported id of that class found there
            for name, f, start in (("vs_0_2_forward_view", 2, (256, 0, 6)), ("vs_0_4_surround_view", 4, (0, 0, 6))):
                s2, i2, m2 = read_occupancy(exported / folder / "occupancy" / name / f"{t:04d}.npz")
                X, Y, Z = m2["volume_size"]
                cut = tuple(slice(o, o + n * f) for o, n in zip(start, (X, Y, Z)))
                blocks = d["semantic"][cut].reshape(X, f, Y, f, Z, f)
                ids = inst[cut].reshape(X, f, Y, f, Z, f)
                best = rank[blocks].max(axis=(1, 3, 5))
                assert np.array_equal(rank[s2], best)
                for a, b, c in np.argwhere(i2)[::31]:
                    cell = (blocks[a, :, b, :, c, :] == s2[a, b, c])
                    assert i2[a, b, c] in ids[a, :, b, :, c, :][cell]


def test_camera_maps_and_lidar_in_the_release_encodings(built, exported):
    import cv2

    from carlaocc.catalog.sensors import LidarStore, SensorStore

    note = json.loads((exported / "carlaocc_export.json").read_text())
    seq = sorted(note["sequences"])[0]
    d = exported / note["sequences"][seq]["folder"]
    sensors = SensorStore(built)
    # load_utils.load_depth: uint16 / 65535 * 80 (our no-surface 0 is the release's 80 m)
    depth = cv2.imread(str(d / "depth" / "image_00" / "0001.png"), -1).astype(np.float32) / 65535 * 80.0
    ours = sensors.read_image(seq, "camera_00", 1, "depth")
    hit = ours > 0
    assert depth.shape == ours.shape and np.allclose(depth[hit], np.minimum(ours[hit], 80), atol=2e-3)
    assert np.all(depth[~hit] == 80.0)
    # load_utils.load_semantics: BGR -> RGB, then the class colours
    rgb = cv2.cvtColor(cv2.imread(str(d / "semantics" / "image_00" / "0000.png"), -1), cv2.COLOR_BGR2RGB)
    lut = {c: i for i, c in enumerate(taxonomy.palette())}
    sem = np.vectorize(lambda r, g, b: lut[(r, g, b)])(rgb[..., 0], rgb[..., 1], rgb[..., 2])
    assert np.array_equal(sem, sensors.read_image(seq, "camera_00", 0, "semantic"))
    assert (d / "normal" / "image_00" / "0001.png").is_file() and not (d / "depth" / "image_05").exists()
    # rendered RGB (load_utils.load_rgb: BGR -> RGB), ours byte for byte
    rgb = cv2.cvtColor(cv2.imread(str(d / "rgb" / "image_00" / "0001.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert np.array_equal(rgb, sensors.read_image(seq, "camera_00", 1, "rgb"))
    # lidar/<frame>.ply: x y z I, our points
    text = (d / "lidar" / "0000.ply").read_text().splitlines()
    n = int(next(h for h in text if h.startswith("element vertex")).split()[2])
    rows = np.loadtxt(text[text.index("end_header") + 1:], ndmin=2)
    pts = LidarStore(built).load(seq, 0)
    assert rows.shape == (n, 4) and n == len(pts["x"])
    assert np.allclose(rows[:, 0], pts["x"], atol=1e-3) and np.allclose(rows[:, 3], np.exp(-0.004 * pts["distance"]), atol=1e-3)


def test_npz_export_uses_the_release_encoding(built, tmp_path):
    from carlaocc.catalog import formats

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / "npz"
    r = cli.invoke(app, ["export", "carlaocc-npz", "--res", "0.1", "--root", built.url, "--out", str(out), "--sequence", seq])
    assert r.exit_code == 0, r.output
    z = np.load(out / seq / "000001.npz")
    d = OccupancyStore(built).read_frame(seq, GridSpec(voxel_size=0.1), 1, ("semantic", "instance"))
    occ = z["occupancy"].astype(np.int64)
    assert np.array_equal(occ[:, 3] >> 11, d["semantic"][occ[:, 0], occ[:, 1], occ[:, 2]])  # the release's bits
    note = json.loads((out / seq / "instances.json").read_text())
    assert note["encoding"] == "bits"
    table = note["instances"]
    keys = [f"{s}:{i}" for s, i in zip(d["semantic"][occ[:, 0], occ[:, 1], occ[:, 2]], d["instance"][occ[:, 0], occ[:, 1], occ[:, 2]])]
    assert [table.get(k, 0) for k in keys] == (occ[:, 3] & 0x7FF).tolist()
    # the simulated actors are the release's moving objects, 1000 and up
    actors = {r[0] for r in query(built, f"SELECT DISTINCT instance_id FROM actors WHERE sequence_id = '{seq}'")[1]}
    moving = [v for k, v in table.items() if int(k.split(":")[1]) in actors]
    assert moving and all(1000 <= v <= 2047 for v in moving)
    assert all(1 <= v <= 999 for k, v in table.items() if int(k.split(":")[1]) not in actors)
    assert formats.load_carlaocc_npz(out / seq / "000001.npz").semantic.shape == (768, 512, 130)
    # the splits travel with every export
    assert sum(seq in (out / "splits" / f"{s}.txt").read_text().split() for s in ("train", "val", "test")) == 1


def test_decimal_encoding_and_exports_add_up_in_one_folder(built, tmp_path):
    seqs = sorted(r[0] for r in query(built, "SELECT sequence_id FROM sequences")[1])
    out = tmp_path / "dec"
    for seq in seqs[:2]:  # two exports into one folder: the second adds to the first
        r = cli.invoke(app, ["export", "carlaocc-release", "--root", built.url, "--out", str(out), "--sequence", seq,
                             "--label-encoding", "decimal"])
        assert r.exit_code == 0, r.output
    note = json.loads((out / "carlaocc_export.json").read_text())
    assert sorted(note["sequences"]) == seqs[:2] and note["encoding"] == "decimal"
    every = [x for s in ("train", "val", "test") for x in read_split(out, s)]
    assert len(every) == 2 * FRAMES and {f for f, _ in every} == {v["folder"] for v in note["sequences"].values()}
    folder = note["sequences"][seqs[0]]["folder"]
    sem, inst, meta = read_occupancy(out / folder / "occupancy" / "vs_0_1" / "0000.npz", decimal=True)
    d = OccupancyStore(built).read_frame(seqs[0], GridSpec(voxel_size=0.1), 0, ("semantic",))
    assert "label_encoding" in meta["keys"] and np.array_equal(sem, d["semantic"]) and inst.max() <= 999
    # another encoding into the same folder is refused, nothing written
    r = cli.invoke(app, ["export", "carlaocc-release", "--root", built.url, "--out", str(out), "--sequence", seqs[2]])
    assert r.exit_code == 2 and "encoding 'decimal'" in r.output
    assert sorted(json.loads((out / "carlaocc_export.json").read_text())["sequences"]) == seqs[:2]


def test_label_table_recorded_and_never_mixed(built, tmp_path, config_file):
    root = tmp_path / "data"
    shutil.copytree(built.root, root)
    store = Store(str(root))
    seq = query(store, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    assert OccupancyStore(store).attrs(seq, GridSpec(voxel_size=0.1))["label_table"] == "release"
    assert query(store, "SELECT DISTINCT label_table FROM towns")[1] == [("release",)]
    assert query(store, "SELECT kind FROM classes WHERE name = 'Pole'")[1] == [("thing",)]
    # a single stage under another table: its upstream is stale, refused before any work
    r = cli.invoke(app, ["run", "--stages", "voxelize", "--res", "0.1", "--root", str(root), "--taxonomy", "carlaocc-v1",
                         "--limit-frames", str(FRAMES), "--config", config_file, "--scheduler", "synchronous"])
    assert r.exit_code == 2 and "stale" in r.output
    # rebuild the scenes and the 0.4 m occupancy under carlaocc-v1: the 0.1 m arrays are now of the other table
    r = cli.invoke(app, ["run", "--stages", "ingest,scenes,splits,voxelize", "--res", "0.4", "--root", str(root),
                         "--taxonomy", "carlaocc-v1", "--limit-frames", str(FRAMES), "--config", config_file,
                         "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    assert query(store, "SELECT kind FROM classes WHERE name = 'Building'")[1] == [("thing",)]
    assert query(store, "SELECT count(*) FROM label_tables")[1] == [(60,)]
    inst = OccupancyStore(store).read_frame(seq, GridSpec(voxel_size=0.4), 0, ("semantic", "instance"))
    assert (inst["instance"][inst["semantic"] == taxonomy.by_name("Building").id] > 0).all()
    assert OccupancyStore(store).attrs(seq, GridSpec(voxel_size=0.4))["label_table"] == "carlaocc-v1"
    for fmt, res in (("carlaocc-release", "0.1"), ("occ3d", "0.1")):
        r = cli.invoke(app, ["export", fmt, "--res", res, "--root", str(root), "--out", str(tmp_path / fmt)])
        assert r.exit_code == 2 and "label table 'release'" in r.output and "carlaocc-v1" in r.output, r.output
    r = cli.invoke(app, ["export", "occ3d", "--res", "0.4", "--root", str(root), "--out", str(tmp_path / "ok")])
    assert r.exit_code == 0, r.output


def test_sequences_selector_builds_a_slice(built, tmp_path, config_file):
    root = tmp_path / "data"
    shutil.copytree(built.root, root)
    r = cli.invoke(app, ["run", "--res", "0.4", "--limit-frames", str(FRAMES), "--root", str(root), "--sequences",
                         "town00_high_*", "--stages", "voxelize", "--config", config_file, "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    occ = OccupancyStore(Store(str(root)))
    built_04 = {s for (s,) in query(Store(str(root)), "SELECT sequence_id FROM sequences")[1]
                if occ.stored_grid(s, 0.4) is not None}
    assert built_04 == {"town00_high_seq000"}
    r = cli.invoke(app, ["run", "--res", "0.4", "--limit-frames", str(FRAMES), "--root", str(root), "--sequences", "nowhere_*",
                         "--stages", "voxelize", "--config", config_file])
    assert r.exit_code == 2 and "matches none" in r.output and "town00_high_seq000" in r.output


def test_a_frame_without_a_pose_is_refused(built, tmp_path):
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import FrameRecord

    root = tmp_path / "data"
    shutil.copytree(built.root, root)
    store = Store(str(root))
    seq = query(store, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    frames = ParquetTable(store, FrameRecord)
    frames.save(seq, [f for f in frames.load([seq]) if f.frame_index != 1])
    out = tmp_path / "out"
    r = cli.invoke(app, ["export", "carlaocc-release", "--root", str(root), "--out", str(out), "--sequence", seq])
    # the release's reader would fail on the frame: refused, naming it, before any file is written
    assert r.exit_code == 2 and f"{seq}: no LiDAR pose for frame 1" in r.output
    assert not out.exists() or not any(out.rglob("*.npz"))


def test_a_recorded_frame_exports_its_own_lidar_scan(tmp_path):
    """A recorded frame has no ray-cast sweep: the release's lidar/<frame>.ply is the recording's
    own ray_cast scan (scan 0 of lidar_recorded/, its intensities), never the semantic one; our
    sweep wins where both exist; a frame with neither gets no file."""
    from carlaocc.catalog.carla_recording import read_ply
    from carlaocc.catalog.sensors import LIDAR_COLUMNS, LidarStore, RecordedLidarStore
    from carlaocc.pipeline.commands.export.release import write_lidar

    store = Store(str(tmp_path / "data"))
    rng = np.random.default_rng(5)
    n = 40
    xyz = rng.uniform(-30, 30, (n, 3))
    scan = (np.arange(n) >= 25).astype(np.uint8)  # 25 points of scan 0, 15 of scan 1
    pts = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "distance": np.linalg.norm(xyz, axis=1), "scan": scan,
           "intensity": np.where(scan == 0, rng.uniform(0.5, 1.0, n), np.nan),
           "cos_angle": np.where(scan == 1, 0.5, np.nan), "object_index": np.where(scan == 1, 7, -1),
           "semantic": np.where(scan == 1, 3, 255).astype(np.uint8), "raycast_distance": np.linalg.norm(xyz, axis=1)}
    RecordedLidarStore(store).save("s", 0, pts)
    assert write_lidar(store, "s", 0, tmp_path / "out") == 1
    got = read_ply(tmp_path / "out" / "lidar" / "0000.ply")
    np.testing.assert_allclose(np.column_stack([got["x"], got["y"], got["z"]]), xyz[:25], atol=1e-4)
    np.testing.assert_allclose(got["I"], pts["intensity"][:25], atol=1e-4)
    # our own sweep of the frame, where there is one, is the one exported
    ours = {c: np.zeros(3, dtype=d) for c, (d, _) in LIDAR_COLUMNS.items()}
    ours["x"] = np.array([1.0, 2.0, 3.0], np.float32)
    LidarStore(store).save("s", 0, ours)
    write_lidar(store, "s", 0, tmp_path / "out")
    assert read_ply(tmp_path / "out" / "lidar" / "0000.ply")["x"].tolist() == [1.0, 2.0, 3.0]
    assert write_lidar(store, "s", 1, tmp_path / "out") == 0
