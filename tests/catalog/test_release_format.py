"""The official release's layout (catalog/formats/carlaocc_release.py): each encoding against an
independent decoding written here from the release's documentation (docs/source/
occ_generation.rst, utils/load_utils.py, tutorials/dataset.py of fengyi233/carlaocc) or against
this project's recording reader, which reads the same files."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.catalog import carla_recording as recording
from carlaocc.catalog.formats import carlaocc_release as rel
from carlaocc.schemas import taxonomy


def _release_reader_folder(line: str) -> tuple[str, int]:
    """The release reader's split-line parsing (tutorials/dataset.py ``_parse_frame_line``)."""
    town_num, seq_num, frame = line.split()
    prefix = "Town10HD_Opt" if town_num == "10" else f"Town{town_num}_Opt"
    return f"{prefix}_Seq{seq_num}", int(frame)


def test_grid_table_is_the_documented_one():
    # docs/source/occ_generation.rst, "Occupancy grid configurations": size, origin, range, volume
    doc = {"vs_0_1": (0.1, (-25.6, -25.6, -3), ((-25.6, 51.2), (-25.6, 25.6), (-3, 10)), (768, 512, 130)),
           "vs_0_2_forward_view": (0.2, (0, -25.6, -2.4), ((0, 51.2), (-25.6, 25.6), (-2.4, 4)), (256, 256, 32)),
           "vs_0_4_surround_view": (0.4, (-25.6, -25.6, -2.4), ((-25.6, 25.6), (-25.6, 25.6), (-2.4, 4)), (128, 128, 16))}
    assert [g.name for g in rel.RELEASE_GRIDS] == list(doc)
    for g in rel.RELEASE_GRIDS:
        voxel_size, origin, ranges, volume = doc[g.name]
        assert g.voxel_size == voxel_size and g.voxel_origin == pytest.approx(origin) and g.volume_size == volume
        # volume size = extent / voxel size
        assert tuple(round((hi - lo) / voxel_size) for lo, hi in ranges) == volume


def _decode_combined_id(v):
    """The release's decoding (utils/data_converter.py decode_combined_id): high 5 bits, low 11."""
    v = np.asarray(v, dtype=np.uint16)
    return (v >> 11) & 0x1F, v & 0x7FF


@settings(max_examples=80, deadline=None)
@given(pairs=st.lists(st.tuples(st.sampled_from([6, 7, 12, 14, 15]), st.integers(0, 5000)), max_size=80),
       moving_frac=st.floats(0, 1), encoding=st.sampled_from(["bits", "decimal"]))
def test_release_instance_ids_never_merge_objects(pairs, moving_frac, encoding):
    sem = np.array([p[0] for p in pairs], np.int64)
    inst = np.array([p[1] for p in pairs], np.int64)
    ids = sorted({i for _, i in pairs if i})
    moving = set(ids[: int(len(ids) * moving_frac)])
    table = rel.release_instance_ids(sem, inst, moving, encoding, "seq")
    things = {(s, i) for s, i in pairs if i != 0}
    assert set(table) == things
    for c in {s for s, _ in things}:
        new = [table[(s, i)] for s, i in things if s == c]
        assert len(set(new)) == len(new)  # unique within a class: never two objects in one
        for s, i in things:
            if s != c:
                continue
            v = table[(s, i)]
            if encoding == "decimal":
                assert 1 <= v <= 999
            elif i in moving:  # the release's moving objects: 1000..2047
                assert 1000 <= v <= 2047
            else:
                assert 1 <= v <= 999
        placed = sorted(i for s, i in things if s == c and (encoding == "decimal" or i not in moving))
        kept = [i % 1000 for i in placed] if encoding == "decimal" else placed
        got = [table[(c, i)] for i in placed]
        ok = len(set(kept)) == len(kept) and all(1 <= k <= 999 for k in kept)
        assert got == (kept if ok else list(range(1, len(placed) + 1)))
        if encoding == "bits":
            actors = sorted(i for s, i in things if s == c and i in moving)
            want = [1000 + i % 1000 for i in actors]
            assert [table[(c, i)] for i in actors] == (want if len(set(want)) == len(want)
                                                       else list(range(1000, 1000 + len(actors))))
    # the same table whatever the order the pairs come in
    assert rel.release_instance_ids(sem[::-1], inst[::-1], moving, encoding, "seq") == table


def test_release_instance_ids_refuse_what_does_not_fit():
    with pytest.raises(ValueError, match="seq7: class 14 has 1000 instances"):
        rel.release_instance_ids(np.full(1000, 14), np.arange(1, 1001), (), "decimal", "seq7")
    with pytest.raises(ValueError, match="seq7: class 14 has 1049 instances; the bits encoding holds 1048"):
        rel.release_instance_ids(np.full(1049, 14), np.arange(1, 1050), range(1, 1050), "bits", "seq7")


def test_remap_is_per_class():
    # our id 5 is a traffic light and its pole (two classes); the pole's ids run past 999 and renumber
    table = rel.release_instance_ids(np.array([7, 6, 6]), np.array([5, 5, 1005]), (), "bits", "s")
    assert table == {(7, 5): 5, (6, 5): 1, (6, 1005): 2}
    keys, vals = rel.instance_lookup(table)
    sem = np.array([[7, 6, 6, 1]], np.uint8)
    inst = np.array([[5, 5, 1005, 0]], np.uint32)
    assert rel.remap_instances(sem, inst, keys, vals).tolist() == [[5, 1, 2, 0]]
    with pytest.raises(ValueError, match="missing"):
        rel.remap_instances(np.array([14]), np.array([3]), keys, vals)


@pytest.mark.parametrize("encoding", ["bits", "decimal"])
def test_occupancy_npz_read_by_the_release_loader(tmp_path, encoding):
    from carlaocc.catalog.formats.carlaocc_npz import load_carlaocc_npz, save_carlaocc_npz

    g = rel.RELEASE_GRIDS[2]
    rng = np.random.default_rng(3)
    sem = np.where(rng.random(g.volume_size) < 0.05, rng.integers(1, 30, g.volume_size), 0).astype(np.uint8)
    top = 2047 if encoding == "bits" else 999
    inst = np.where(np.isin(sem, taxonomy.thing_ids()), rng.integers(1, top + 1, g.volume_size), 0).astype(np.uint32)
    rows = save_carlaocc_npz(tmp_path / "0000.npz", sem, inst, g.voxel_size, g.voxel_origin, encoding)
    # utils/load_utils.py load_pano_occ: np.load, occ_sparse2dense, decode_combined_id
    z = np.load(tmp_path / "0000.npz")
    occ = z["occupancy"]
    assert occ.dtype == np.uint16 and occ.shape == (rows, 4) and rows == np.count_nonzero(sem)
    dense = np.zeros(tuple(z["volume_size"]), np.uint16)
    dense[occ[:, 0], occ[:, 1], occ[:, 2]] = occ[:, 3]
    if encoding == "bits":
        assert sorted(z.files) == sorted(["occupancy", "voxel_size", "voxel_origin", "volume_size"])
        s, i = _decode_combined_id(dense)
    else:  # the documentation's formula, and the file says which it is
        assert str(z["label_encoding"]) == "decimal"
        s, i = dense.astype(np.int64) // 1000, dense.astype(np.int64) % 1000
    assert np.array_equal(s, sem) and np.array_equal(i, inst)
    assert float(z["voxel_size"]) == 0.4 and np.allclose(z["voxel_origin"], g.voxel_origin)
    back = load_carlaocc_npz(tmp_path / "0000.npz")
    assert np.array_equal(back.semantic, sem) and np.array_equal(back.instance, inst)


def test_release_priority_is_the_sem_z_order():
    # utils/labels.py sem_z_order (class id -> rank; higher wins), transcribed here
    z = {0: 0, 23: 1, 10: 2, 25: 3, 1: 4, 24: 5, 2: 6, 27: 7, 29: 8, 5: 9, 28: 10, 4: 11, 3: 12, 26: 13, 6: 14, 7: 15,
         8: 16, 20: 17, 21: 18, 22: 19, 9: 20, 12: 21, 13: 22, 19: 23, 18: 24, 14: 25, 15: 26, 16: 27, 17: 28, 11: 29}
    assert list(rel.RELEASE_PRIORITY) == sorted((c for c in z if c), key=lambda c: -z[c])


def test_folder_names_follow_the_release_reader():
    assert rel.town_numbers(["town00", "town01"]) == {"town00": 1, "town01": 2}
    numbers = rel.town_numbers([f"town{i:02d}" for i in range(9)])
    assert list(numbers.values()) == [1, 2, 3, 4, 5, 6, 7, 10, 11]
    # a recorded town named like the release's keeps its number
    assert rel.town_numbers(["Town03_Opt", "town00"]) == {"Town03_Opt": 3, "town00": 1}
    assert rel.town_numbers(["Town10HD_Opt"]) == {"Town10HD_Opt": 10}
    for town, seq in ((1, 0), (10, 7), (11, 12)):
        folder = rel.sequence_folder(town, seq)
        for frame in (0, 999):
            (line,) = rel.split_lines(town, seq, [frame]).splitlines()
            assert _release_reader_folder(line) == (folder, frame)
    assert rel.sequence_folder(10, 3) == "Town10HD_Opt_Seq03"
    with pytest.raises(ValueError):
        rel.sequence_folder(1, 100)


def test_calib_poses_depth_semantics_lidar_read_by_the_recording_reader(tmp_path):
    """Every file written here reads back through catalog/carla_recording.py, the reader of the
    same layout that imports CARLA recordings."""
    from carlaocc.pipeline.tasks.recording import rig_from_calib
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.sensors import camera_poses

    rig = RigConfig()
    optical = camera_poses(rig)
    body = {c.name.replace("camera_", "cam_"): optical[c.name] @ np.linalg.inv(recording.OPTICAL_FROM_BODY)
            for c in rig.cameras}
    c0 = rig.cameras[0]
    (tmp_path / "calib.yaml").write_text(rel.calib_yaml(c0.width, c0.height, c0.hfov_deg, np.asarray(c0.intrinsics), body))
    calib = recording.read_calib(tmp_path / "calib.yaml")
    back = rig_from_calib(calib, rig)
    for a, b in zip(rig.cameras, back.cameras, strict=True):
        assert a.name == b.name
        assert (a.x, a.y, a.z, a.width, a.height) == pytest.approx((b.x, b.y, b.z, b.width, b.height), abs=1e-5)
        assert abs(np.remainder(a.yaw_deg - b.yaw_deg + 180, 360) - 180) < 1e-4
    # the release's own reading of calib.yaml (utils/load_utils.py load_calibration)
    doc = yaml.safe_load((tmp_path / "calib.yaml").read_text())
    assert set(doc["cam_settings"]) == {"width", "height", "fov", "intrinsics"}
    assert np.array(doc["sensors"]["cam_00"]["transform"]).shape == (4, 4)
    # poses: frame number and 16 values; np.loadtxt as the release reader does
    poses = {t: np.array([[1, 0, 0, t], [0, 1, 0, 2 * t], [0, 0, 1, 1.73], [0, 0, 0, 1]], float) for t in range(3)}
    (tmp_path / "lidar.txt").write_text(rel.pose_lines(poses))
    got, bad = recording.read_poses(tmp_path / "lidar.txt")
    assert not bad and all(np.allclose(got[t], poses[t]) for t in poses)
    arr = np.loadtxt(tmp_path / "lidar.txt")
    assert arr.shape == (3, 17) and np.allclose(arr[2, 1:].reshape(4, 4), poses[2])
    # depth: metres to uint16 and back within one step of the 80 m / 65535 scale; no surface = 80 m
    d = np.array([[0.0, 0.5, 12.345, 79.9, 200.0]], np.float32)
    back_d = recording.decode_depth(rel.encode_depth(d))
    assert np.allclose(back_d[0, 1:4], d[0, 1:4], atol=80 / 65535) and back_d[0, 0] == 80.0 and back_d[0, 4] == 80.0
    # semantics: class colours, read back to ids
    ids = np.arange(30, dtype=np.uint8).reshape(5, 6)
    dec, unknown = recording.decode_semantics(rel.encode_semantics(ids, taxonomy.palette()))
    assert unknown == 0 and np.array_equal(dec, ids)
    # LiDAR: ASCII PLY x y z I, intensity exp(-0.004 d)
    pts = np.array([[10.0, 0.0, 0.0], [0.0, -5.0, 1.0]])
    (tmp_path / "0000.ply").write_text(rel.ply_text(pts))
    ply = recording.read_ply(tmp_path / "0000.ply")
    assert list(ply) == ["x", "y", "z", "I"]
    assert np.allclose(np.column_stack([ply["x"], ply["y"], ply["z"]]), pts, atol=1e-4)
    assert np.allclose(ply["I"], np.exp(-0.004 * np.linalg.norm(pts, axis=1)), atol=1e-4)


def test_normals_follow_d2nt_visualisation():
    from d2nt.utils import get_normal_vis

    n = np.array([[[0.0, 0.0, -1.0], [0.6, -0.8, 0.0], [1.0, 0.0, 0.0]]], np.float32)
    assert np.array_equal(rel.encode_normals(n), (get_normal_vis(n) * 255).astype(np.uint8))
