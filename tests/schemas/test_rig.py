import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from carlaocc.schemas.rig import CameraSpec, LidarSpec, RigConfig


def _project(cam: CameraSpec, p_ego) -> tuple[float, float, float]:
    """Project an ego-frame point into the camera image: (u, v, depth)."""
    T = np.array(cam.camera_to_ego())
    p = np.linalg.inv(T) @ np.array([*p_ego, 1.0])
    uvw = np.array(cam.intrinsics) @ p[:3]
    return uvw[0] / uvw[2], uvw[1] / uvw[2], p[2]


def test_reference_rig_intrinsics_are_derived():
    rig = RigConfig()
    assert [c.name for c in rig.cameras] == [f"camera_0{i}" for i in range(6)]
    cam = rig.cameras[0]
    assert (cam.width, cam.height) == (1408, 376)
    f = 1408 / (2 * math.tan(math.radians(103.744808 / 2)))
    assert cam.focal_px == pytest.approx(f) and cam.focal_px == pytest.approx(552.55, abs=0.01)
    K = np.array(cam.intrinsics)
    np.testing.assert_allclose(K, [[f, 0, 704], [0, f, 188], [0, 0, 1]])
    assert cam.vfov_deg == pytest.approx(math.degrees(2 * math.atan(188 / f)))


def test_carla_positions_convert_once_to_our_frame():
    rig = RigConfig()
    by = {c.name: c for c in rig.cameras}
    # camera_00 sits at CARLA y = -0.3 (left in CARLA's y-right frame): ours y = +0.3
    T = np.array(by["camera_00"].sensor_to_ego())
    np.testing.assert_allclose(T[:3, 3], [0.8, 0.3, 1.55])
    # a point 10 m straight ahead of camera_00 lands on the principal point
    u, v, d = _project(by["camera_00"], [10.8, 0.3, 1.55])
    assert (u, v, d) == pytest.approx((704.0, 188.0, 10.0))
    # camera_02 has CARLA yaw -90 (turned left): it sees a point on our +y side
    u, v, d = _project(by["camera_02"], [0.0, 10.0, 1.55])
    assert d > 0 and u == pytest.approx(704.0) and v == pytest.approx(188.0)
    # camera_03 (yaw +90, right) sees -y; the rear pair sees -x
    assert _project(by["camera_03"], [0.0, -10.0, 1.55])[2] > 0
    assert _project(by["camera_04"], [-10.0, 0.3, 1.55])[2] > 0
    # image axes: a point to the camera's right has larger u, a point lower has larger v
    u_r, _, _ = _project(by["camera_00"], [10.8, -1.0, 1.55])
    _, v_d, _ = _project(by["camera_00"], [10.8, 0.3, 0.5])
    assert u_r > 704.0 and v_d > 188.0
    for cam in rig.cameras:
        R = np.array(cam.camera_to_ego())[:3, :3]
        assert np.linalg.det(R) == pytest.approx(1.0)


def test_lidar_beams_and_points():
    lidar = RigConfig().lidar
    assert lidar.z == 1.73 and lidar.channels == 32 and lidar.range_m == 80.0
    el = lidar.beam_elevations_deg
    assert len(el) == 32 and el[0] == 10.0 and el[-1] == pytest.approx(-30.0)
    assert lidar.points_per_frame == 12_500


def test_bad_rigs_are_refused():
    with pytest.raises(ValidationError, match="unique"):
        RigConfig(cameras=(CameraSpec(name="a"), CameraSpec(name="a")))
    with pytest.raises(ValidationError):
        CameraSpec(name="c", hfov_deg=180.0)
    with pytest.raises(ValidationError, match="below"):
        LidarSpec(upper_fov_deg=-30, lower_fov_deg=10)
    with pytest.raises(ValidationError):
        RigConfig(camera=())


def test_directions_in_words_cover_the_compass():
    from carlaocc.schemas.rig import facing

    words = [facing(a) for a in (0, 45, 90, 135, 180, -135, -90, -45)]
    assert words == ["front", "front-left", "left", "rear-left", "rear", "rear-right", "right", "front-right"]
    # sector edges: 22.4 deg is still front, 22.6 front-left; -180 and 180 are both rear
    assert (facing(22.4), facing(22.6), facing(-180.0), facing(359.0)) == ("front", "front-left", "rear", "front")


def test_reference_rig_in_the_dataset_frame():
    from carlaocc.schemas.rig import camera_roles, rig_lines, stereo_pairs

    rig = RigConfig()
    by = {c.name: c for c in rig.cameras}
    # positions agree with the pose the pipeline uses (sensor_to_ego), yaw with its rotation
    for cam in rig.cameras:
        T = np.array(cam.sensor_to_ego())
        np.testing.assert_allclose(cam.ego_position(), T[:3, 3])
        yaw = math.radians(cam.ego_yaw_deg)
        np.testing.assert_allclose([math.cos(yaw), math.sin(yaw)], [T[0, 0], T[1, 0]], atol=1e-12)
    assert [by[n].direction for n in sorted(by)] == ["front", "front", "left", "right", "rear", "rear"]
    assert by["camera_04"].ego_yaw_deg == 180.0
    pairs = stereo_pairs(rig.cameras)
    assert [(a, b) for a, b, _ in pairs] == [("camera_00", "camera_01"), ("camera_05", "camera_04")]
    assert [base for _, _, base in pairs] == pytest.approx([0.6, 0.6])
    # "left" of a pair is the left eye: a far point straight along the pair's axis has a positive
    # disparity u_left - u_right in the images themselves
    for left, right, far in (("camera_00", "camera_01", [60.0, 0.0, 1.55]), ("camera_05", "camera_04", [-60.0, 0.0, 1.55])):
        assert _project(by[left], far)[0] - _project(by[right], far)[0] > 0
    roles = camera_roles(rig.cameras)
    assert roles["camera_05"] == "rear, stereo left (with camera_04)" and roles["camera_02"] == "left"
    lines = rig_lines(rig)
    assert lines[0].startswith("camera_00  x +0.80  y +0.30  z 1.55  yaw   +0.0 deg  front, stereo left")
    assert "y -0.46" in lines[3] and "deg  right  1408x376" in lines[3]  # camera_03: y right of the ego in words
    assert lines[-1] == "stereo pair camera_05 (left) / camera_04 (right): baseline 0.60 m"
    # a rotated single camera: no pair, its own direction
    one = (CameraSpec(name="c", x=1.0, y=0.5, yaw_deg=-45.0), CameraSpec(name="d", x=1.0, y=-0.5, yaw_deg=0.0))
    assert stereo_pairs(one) == [] and camera_roles(one) == {"c": "front-left", "d": "front"}


def test_roles_from_poses_agree_with_the_rig():
    from carlaocc.schemas.rig import camera_roles, pose_roles

    rig = RigConfig()
    # the optical frames' poses in the LiDAR frame (as sensor_poses and the frames table give them)
    to_lidar = np.linalg.inv(np.array(rig.lidar.sensor_to_ego()))
    poses = {c.name: (to_lidar @ np.array(c.camera_to_ego())).tolist() for c in rig.cameras}
    assert pose_roles(poses) == camera_roles(rig.cameras)
    assert pose_roles(poses)["camera_04"] == "rear, stereo right (with camera_05)"


@given(st.floats(-1000.0, 1000.0, allow_nan=False))
def test_facing_names_the_nearest_of_eight_directions(yaw):
    from carlaocc.schemas.rig import facing

    names = ["front", "front-left", "left", "rear-left", "rear", "rear-right", "right", "front-right"]
    word = facing(yaw)
    # the named direction is within half a sector (22.5 deg, with rounding slack) of the heading
    off = (yaw - 45.0 * names.index(word) + 180.0) % 360.0 - 180.0
    assert abs(off) <= 22.5 + 1e-9
    assert facing(yaw + 360.0) == word or abs(abs(off) - 22.5) < 1e-6
