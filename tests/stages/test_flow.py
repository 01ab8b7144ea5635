"""Occupancy flow of dynamic instances (stages/voxelize/flow.py)."""

from __future__ import annotations

import numpy as np
import pytest

from carlaocc.stages.voxelize.flow import instance_flow


def _yaw(theta: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = t
    return T


def _volume() -> np.ndarray:
    inst = np.zeros((6, 5, 4), dtype=np.uint32)
    inst[1:3, 1:3, 0:2] = 7  # actor 7
    inst[4, 0:2, 1] = 9  # actor 9
    inst[0, 4, 3] = 3  # a static thing (no actor state)
    return inst


def _centres(inst, origin, voxel_size, T=None):
    T = np.eye(4) if T is None else T
    ijk = np.argwhere(inst != 0)
    p = np.asarray(origin) + (ijk + 0.5) * voxel_size
    return ijk, p @ T[:3, :3].T + T[:3, 3]


def test_pure_translation_same_vector_and_others_zero():
    inst = _volume()
    flow = instance_flow(inst, (-1.0, 2.0, 0.5), 0.25, np.array([7, 9], np.uint32),
                         np.zeros((2, 3)), np.array([[1.5, -2.0, 0.25], [0.0, 3.0, 0.0]]), np.zeros((2, 3)), np.eye(4))
    assert flow.dtype == np.float16 and flow.shape == inst.shape + (3,)
    np.testing.assert_array_equal(flow[inst == 7], np.tile(np.float16([1.5, -2.0, 0.25]), ((inst == 7).sum(), 1)))
    np.testing.assert_array_equal(flow[inst == 9], np.tile(np.float16([0.0, 3.0, 0.0]), ((inst == 9).sum(), 1)))
    # free space and the static/unknown instance 3 are zero
    assert not flow[(inst != 7) & (inst != 9)].any()


def test_pure_yaw_rotation_about_centre():
    inst = _volume()
    origin, voxel_size = (-1.0, 2.0, 0.5), 0.25
    c = np.array([0.3, 2.4, 0.0])
    flow = instance_flow(inst, origin, voxel_size, np.array([7], np.uint32), c[None], np.zeros((1, 3)),
                         np.array([[0.0, 0.0, 1.0]]), np.eye(4))
    ijk, p = _centres(inst, origin, voxel_size)
    sel = inst[tuple(ijk.T)] == 7
    expect = np.stack([-(p[sel, 1] - c[1]), p[sel, 0] - c[0], np.zeros(sel.sum())], axis=1)
    np.testing.assert_allclose(flow[tuple(ijk[sel].T)].astype(np.float64), expect, atol=2e-3)
    assert not flow[inst == 9].any()


def test_rotated_lidar_expresses_flow_in_lidar_axes():
    inst = _volume()
    # LiDAR yawed +90 degrees in the world: its x axis is the world's +y
    T = _yaw(np.pi / 2, (10.0, -4.0, 1.0))
    flow = instance_flow(inst, (0.0, 0.0, 0.0), 0.5, np.array([7], np.uint32), np.zeros((1, 3)),
                         np.array([[0.0, 2.0, 0.0]]), np.zeros((1, 3)), T)
    # moving along world +y = LiDAR +x
    np.testing.assert_allclose(flow[inst == 7].astype(np.float64), np.tile([2.0, 0.0, 0.0], ((inst == 7).sum(), 1)),
                               atol=1e-3)
    # rotation about a world centre: velocity from the world-frame centre, then rotated to LiDAR axes
    c = np.array([9.0, -3.0, 0.0])
    flow = instance_flow(inst, (0.0, 0.0, 0.0), 0.5, np.array([7], np.uint32), c[None], np.zeros((1, 3)),
                         np.array([[0.0, 0.0, 0.5]]), T)
    ijk, pw = _centres(inst, (0.0, 0.0, 0.0), 0.5, T)
    sel = inst[tuple(ijk.T)] == 7
    vw = np.cross([0.0, 0.0, 0.5], pw[sel] - c)
    np.testing.assert_allclose(flow[tuple(ijk[sel].T)].astype(np.float64), vw @ T[:3, :3], atol=5e-3)


def test_unknown_ids_and_empty_inputs_give_zero():
    inst = _volume()
    flow = instance_flow(inst, (0, 0, 0), 0.5, np.array([42, 43], np.uint32), np.zeros((2, 3)), np.ones((2, 3)),
                         np.ones((2, 3)), np.eye(4))
    assert flow.dtype == np.float16 and not flow.any()
    flow = instance_flow(inst, (0, 0, 0), 0.5, np.zeros(0, np.uint32), np.zeros((0, 3)), np.zeros((0, 3)),
                         np.zeros((0, 3)), np.eye(4))
    assert flow.shape == inst.shape + (3,) and not flow.any()
    with pytest.raises(ValueError):
        instance_flow(inst, (0, 0, 0), 0.5, np.array([7, 7], np.uint32), np.zeros((2, 3)), np.zeros((2, 3)),
                      np.zeros((2, 3)), np.eye(4))


def test_tile_equals_slice_of_whole():
    rng = np.random.default_rng(3)
    inst = rng.choice(np.array([0, 0, 0, 5, 11, 12, 99], np.uint32), size=(12, 10, 6))
    origin, voxel_size = np.array([-3.0, -2.5, -1.0]), 0.25  # dyadic: the tile origin is exact
    ids = np.array([12, 5, 11], np.uint32)  # unsorted on purpose
    C = rng.normal(size=(3, 3)) * 5
    Vl = rng.normal(size=(3, 3))
    W = rng.normal(size=(3, 3)) * 0.3
    T = _yaw(0.7, (100.0, 50.0, 2.0))
    whole = instance_flow(inst, origin, voxel_size, ids, C, Vl, W, T)
    sl = (slice(4, 9), slice(3, 10), slice(2, 5))
    tile_origin = origin + np.array([4, 3, 2]) * voxel_size
    tile = instance_flow(inst[sl], tile_origin, voxel_size, ids, C, Vl, W, T)
    np.testing.assert_array_equal(tile, whole[sl])
    # every voxel of actor 5 carries its own rigid-body velocity
    assert np.abs(whole[inst == 5]).max() > 0 and not whole[(inst == 0) | (inst == 99)].any()


def test_actor_voxels_inside_boxes_give_the_dense_flow():
    from carlaocc.stages.voxelize.flow import actor_voxels, voxel_flow

    rng = np.random.default_rng(3)
    inst = np.zeros((9, 8, 7), dtype=np.uint32)
    inst[1:4, 2:5, 1:3] = 7
    inst[5:9, 0:2, 4:7] = 9
    inst[6, 6, 6] = 9  # a second mesh of actor 9, in another box
    inst[0, 7, 0] = 3  # a static thing: never an actor voxel
    things = np.array([[7, 0, 5, 1, 6, 0, 4], [9, 4, 9, 0, 3, 3, 7], [9, 6, 7, 6, 7, 6, 7], [3, 0, 1, 7, 8, 0, 1],
                       [9, 0, 0, 0, 0, 0, 0]])  # an empty box is ignored
    ids = np.array([9, 7, 11], np.uint32)  # 11: an actor outside this volume
    C, Vl, W = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    T = _yaw(0.4, (3.0, -2.0, 1.0))
    flat, actor = actor_voxels(inst, things, ids)
    assert sorted(flat) == sorted(np.flatnonzero((inst == 7) | (inst == 9)))
    assert len(set(flat)) == len(flat)  # overlapping boxes of one actor find a voxel once
    np.testing.assert_array_equal(ids[actor], inst.reshape(-1)[flat])
    dense = instance_flow(inst, (0.5, -1.0, 2.0), 0.1, ids, C, Vl, W, T)
    sparse = np.zeros_like(dense)
    sparse.reshape(-1, 3)[flat] = voxel_flow(flat, inst.shape, (0.5, -1.0, 2.0), 0.1, actor, C, Vl, W, T)
    np.testing.assert_array_equal(sparse, dense)
    # a box too small to hold the actor's voxels misses them: the boxes are the contract
    assert len(actor_voxels(inst, np.array([[7, 1, 2, 2, 3, 1, 2]]), np.array([7]))[0]) == 1


def test_actor_voxels_refuses_repeated_ids():
    from carlaocc.stages.voxelize.flow import actor_voxels

    with pytest.raises(ValueError, match="unique"):
        actor_voxels(np.zeros((2, 2, 2), np.uint32), np.zeros((0, 7), np.int64), np.array([4, 4]))
