import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from stages.metrics import isolated_mask_reference, sequence_continuity, spatial_continuity_counts


def test_single_voxel_is_isolated_and_pair_is_not():
    sem = np.zeros((4, 4, 4), np.uint8)
    sem[1, 1, 1] = 3
    c = spatial_continuity_counts(sem)
    assert c.occupied[3] == 1 and c.isolated[3] == 1 and c.score == 0.0
    sem[1, 1, 2] = 3
    c = spatial_continuity_counts(sem)
    assert c.occupied[3] == 2 and c.isolated[3] == 0 and c.score == 1.0


def test_neighbour_of_another_class_does_not_connect():
    sem = np.zeros((3, 3, 3), np.uint8)
    sem[1, 1, 1], sem[1, 1, 2] = 3, 14
    c = spatial_continuity_counts(sem)
    assert c.isolated[3] == 1 and c.isolated[14] == 1 and c.score == 0.0


def test_diagonal_is_not_a_face_neighbour():
    sem = np.zeros((3, 3, 3), np.uint8)
    sem[0, 0, 0] = sem[1, 1, 1] = 5
    assert spatial_continuity_counts(sem).isolated[5] == 2


def test_empty_grid_has_no_score():
    assert np.isnan(spatial_continuity_counts(np.zeros((2, 2, 2), np.uint8)).score)


@settings(max_examples=60, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9)),
              elements=st.integers(0, 4)))
def test_agrees_with_brute_force_reference(sem):
    c = spatial_continuity_counts(sem)
    ref = isolated_mask_reference(sem)
    for cls in range(1, 5):
        assert c.occupied[cls] == int((sem == cls).sum())
        assert c.isolated[cls] == int((ref & (sem == cls)).sum())
    assert c.occupied[0] == 0 and c.isolated[0] == 0


def test_sequence_sums_frames():
    a = np.zeros((3, 3, 3), np.uint8)
    a[1, 1, 1] = 1
    b = np.zeros((3, 3, 3), np.uint8)
    b[0, 0, :] = 1
    total = sequence_continuity([spatial_continuity_counts(a), spatial_continuity_counts(b)])
    assert total.occupied[1] == 4 and total.isolated[1] == 1 and total.score == 0.75
