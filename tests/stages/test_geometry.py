import pytest
import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.geometry import (angular_velocity, box_center, concatenate, invert_pose, is_watertight,
                                      pose_from_list, pose_matrix, pose_to_list, rotation_matrix, tilt_to_normal,
                                      transform_points, yaw_pitch_roll)

MESHES = [trimesh.creation.box((1, 2, 3)), trimesh.creation.icosphere(2), trimesh.creation.cylinder(0.5, 2.0),
          trimesh.creation.capsule(1.0, 0.3)]


def test_watertight_agrees_with_trimesh_on_closed_and_broken_meshes():
    for m in MESHES:
        assert is_watertight(m.faces) == (m.is_watertight and m.is_winding_consistent)
        assert not is_watertight(m.faces[:-1])  # a hole
        flipped = m.faces.copy()
        flipped[0] = flipped[0][::-1]
        assert not is_watertight(flipped)  # inconsistent winding
    assert not is_watertight(np.zeros((0, 3), np.int64))


@settings(max_examples=50, deadline=None)
@given(x=st.floats(-100, 100), y=st.floats(-100, 100), z=st.floats(-5, 5), yaw=st.floats(-7, 7))
def test_pose_inverse_and_flattening(x, y, z, yaw):
    T = pose_matrix(x, y, z, yaw)
    np.testing.assert_allclose(invert_pose(T) @ T, np.eye(4), atol=1e-9)
    np.testing.assert_array_equal(pose_from_list(pose_to_list(T)), T)
    p = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(transform_points(invert_pose(T), transform_points(T, p)), p, atol=1e-9)


def test_yaw_is_right_handed_about_z():
    # +90 degrees turns +X into +Y
    np.testing.assert_allclose(transform_points(pose_matrix(0, 0, 0, np.pi / 2), [[1.0, 0, 0]]), [[0, 1.0, 0]], atol=1e-12)


def test_concatenate_offsets_faces():
    a, b = MESHES[0], MESHES[1]
    v, f = concatenate([(a.vertices, a.faces), (b.vertices, b.faces)])
    assert len(v) == len(a.vertices) + len(b.vertices)
    np.testing.assert_array_equal(f[len(a.faces):], b.faces + len(a.vertices))
    assert is_watertight(f)


# ------------------------------------------------------------------ full rotations (yaw, pitch, roll)

ANGLE = st.floats(-3.1, 3.1)
PITCH = st.floats(-1.5, 1.5)


@settings(max_examples=100, deadline=None)
@given(yaw=ANGLE, pitch=PITCH, roll=ANGLE)
def test_rotation_is_orthonormal_and_round_trips(yaw, pitch, roll):
    R = rotation_matrix(yaw, pitch, roll)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # the same as the three elementary rotations Rz Ry Rx
    Rz = rotation_matrix(yaw)
    Ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    np.testing.assert_allclose(R, Rz @ Ry @ Rx, atol=1e-12)
    back = yaw_pitch_roll(R)
    np.testing.assert_allclose(rotation_matrix(*back), R, atol=1e-9)
    np.testing.assert_allclose(back, (yaw, pitch, roll), atol=1e-9)


def test_rotation_signs_follow_rep103():
    # positive pitch: the nose (+X) goes down; positive roll: the left side (+Y) goes up
    assert rotation_matrix(0.0, 0.3, 0.0)[2, 0] < 0
    assert rotation_matrix(0.0, 0.0, 0.3)[2, 1] > 0
    # yaw only is the exact planar matrix
    c, s = np.cos(0.7), np.sin(0.7)
    assert np.array_equal(rotation_matrix(0.7), [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    assert np.array_equal(pose_matrix(1, 2, 3, 0.7, 0.0, 0.0), pose_matrix(1, 2, 3, 0.7))


@settings(max_examples=100, deadline=None)
@given(yaw=ANGLE, nx=st.floats(-0.5, 0.5), ny=st.floats(-0.5, 0.5))
def test_tilt_to_normal_stands_the_body_on_the_surface(yaw, nx, ny):
    up = np.array([nx, ny, 1.0])
    pitch, roll = tilt_to_normal(yaw, up)
    R = rotation_matrix(yaw, float(pitch), float(roll))
    # body up = the surface normal; the heading keeps its yaw; forward lies in the surface
    np.testing.assert_allclose(R[:, 2], up / np.linalg.norm(up), atol=1e-12)
    assert np.cos(np.arctan2(R[1, 0], R[0, 0]) - yaw) == pytest.approx(1.0)
    assert abs(R[:, 0] @ up) < 1e-12


def test_level_surface_gives_positive_zero_angles():
    pitch, roll = tilt_to_normal(np.array([0.0, 2.0, -3.0]), np.array([0.0, 0.0, 1.0]))
    assert np.array_equal(pitch, [0.0, 0.0, 0.0]) and not np.signbit(pitch).any() and not np.signbit(roll).any()


@settings(max_examples=50, deadline=None)
@given(yaw=ANGLE, pitch=st.floats(-1.2, 1.2), roll=ANGLE, rates=st.tuples(*[st.floats(-2, 2)] * 3))
def test_angular_velocity_matches_the_rotation_derivative(yaw, pitch, roll, rates):
    dy, dp, dr = rates
    h = 1e-6
    R0 = rotation_matrix(yaw - dy * h, pitch - dp * h, roll - dr * h)
    R1 = rotation_matrix(yaw + dy * h, pitch + dp * h, roll + dr * h)
    W = (R1 - R0) / (2 * h) @ rotation_matrix(yaw, pitch, roll).T  # the skew matrix of omega
    w = angular_velocity(yaw, pitch, roll, dy, dp, dr)
    np.testing.assert_allclose(w, [W[2, 1], W[0, 2], W[1, 0]], atol=1e-6)


def test_angular_velocity_of_a_yaw_is_exact():
    w = angular_velocity(np.array([0.3, -2.0]), np.zeros(2), np.zeros(2), np.array([0.5, -0.1]), np.zeros(2), np.zeros(2))
    assert np.array_equal(w, [[0.0, 0.0, 0.5], [0.0, 0.0, -0.1]]) and not np.signbit(w[:, :2]).any()


def test_box_center_is_half_the_height_up_the_body():
    T = pose_matrix(1.0, 2.0, 3.0, 0.4, 0.2, -0.1)
    np.testing.assert_allclose(box_center(T, 2.0), transform_points(T, [[0.0, 0.0, 1.0]])[0])
    assert box_center(pose_matrix(1.0, 2.0, 3.0, 0.4), 1.5) == [1.0, 2.0, 3.75]
