import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.geometry import (concatenate, invert_pose, is_watertight, pose_from_list, pose_matrix,
                             pose_to_list, transform_points)

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
