"""A recorded LiDAR scan against our scene (stages/sensors/recorded_lidar.py): our ranges along
the recorded beams against an analytic reference (a ground plane and a wall), and the agreement's
figures on scans whose errors are known."""

from __future__ import annotations

import numpy as np
import pytest

from carlaocc.schemas.meshes import SceneMesh
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors import RayScene
from carlaocc.stages.sensors.recorded_lidar import beam_ranges, lidar_agreement

TERRAIN, BUILDING, CAR = 10, 3, 14
H = 1.73  # the LiDAR above the ground (LiDAR frame: the ground is z = -H)
WALL_X = 20.0


def _plane(V, semantic, instance=0, name=""):
    return SceneMesh(np.asarray(V, float), np.array([[0, 1, 2], [0, 2, 3]]), semantic, instance, instance == 0, False,
                     name=name, asset_id=name)


def _scene(car=False):
    meshes = [_plane([[-100, -100, -H], [100, -100, -H], [100, 100, -H], [-100, 100, -H]], TERRAIN, name="ground"),
              # a wall facing -x at x = 20, 50 m wide, 10 m tall
              _plane([[WALL_X, -25, -H], [WALL_X, 25, -H], [WALL_X, 25, 10], [WALL_X, -25, 10]], BUILDING, 5, "wall")]
    if car:  # a car's rear face at x = 8 across y in [-1, 1], up to 1.5 m above the ground
        meshes.append(_plane([[8, 1, -H], [8, -1, -H], [8, -1, -H + 1.5], [8, 1, -H + 1.5]], CAR, 7, "car"))
    return RayScene(flatten(meshes))


def _beams(n=2000, seed=0):
    """Unit beam directions below the horizon, within 40 degrees of +x."""
    rng = np.random.default_rng(seed)
    el, az = np.radians(rng.uniform(-25, -2, n)), np.radians(rng.uniform(-40, 40, n))
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


def _reference_ranges(d):
    """Nearest of the ground plane z = -H and the wall x = WALL_X (|y| <= 25, z <= 10), per beam."""
    t_ground = np.where(d[:, 2] < 0, -H / np.where(d[:, 2] < 0, d[:, 2], -1), np.inf)
    t_wall = np.where(d[:, 0] > 0, WALL_X / np.where(d[:, 0] > 0, d[:, 0], 1), np.inf)
    hit = d * t_wall[:, None]
    t_wall = np.where((np.abs(hit[:, 1]) <= 25) & (hit[:, 2] <= 10) & (hit[:, 2] >= -H), t_wall, np.inf)
    return np.minimum(t_ground, t_wall)


def test_our_beam_ranges_are_the_analytic_ones():
    d = _beams()
    ref = _reference_ranges(d)
    points = np.round(d * ref[:, None], 4)  # a recording's points, 4 decimals as the saver writes them
    ours, face = beam_ranges(_scene(), points)
    assert (face >= 0).all()
    np.testing.assert_allclose(ours, ref, atol=2e-3)
    # a beam with no direction (a point at the origin) and one into the sky hit nothing
    t, f = beam_ranges(_scene(), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]]))
    assert np.isinf(t).all() and (f == -1).all()


def test_agreement_counts_the_points_off_by_more_than_the_tolerance():
    d = _beams()
    ref = _reference_ranges(d)
    tags = np.full(len(d), 255, np.uint8)
    exact, summary = lidar_agreement(_scene(), d * ref[:, None], tags)
    assert (summary.points, summary.static_points, summary.missed) == (len(d), len(d), 0)
    assert summary.within == 1.0 and summary.median_m < 1e-3 and summary.p95_m < 2e-3
    # 150 points 0.3 m too far, 50 of them 0.05 m too near: the 150 fail, the 50 pass
    far = d * ref[:, None]
    far[:150] *= ((ref[:150] + 0.3) / ref[:150])[:, None]
    far[150:200] *= ((ref[150:200] - 0.05) / ref[150:200])[:, None]
    _, summary = lidar_agreement(_scene(), far, tags)
    assert summary.within == pytest.approx(1 - 150 / len(d))
    assert summary.p95_m == pytest.approx(0.3, abs=2e-3)  # 7.5 % of the points are 0.3 m off
    # points in the sky of our scene (the recording saw something we lack): missed, infinite error
    sky = np.concatenate([d * ref[:, None], [[0.0, 0.0, 30.0]] * 200])
    ours, summary = lidar_agreement(_scene(), sky, np.full(len(sky), 255, np.uint8))
    assert summary.missed == 200 and np.isinf(ours[-200:]).all() and np.isinf(summary.p95_m)
    assert summary.within == pytest.approx(len(d) / len(sky)) and np.isfinite(summary.median_m)


def test_road_users_are_left_out_by_either_labelling():
    d = _beams()
    scene = _scene(car=True)
    ours, face = beam_ranges(scene, d)
    on_car = scene.labels(face)[0] == CAR
    assert on_car.sum() > 20
    # the recording has no car there (it moved): its points lie on the ground or wall behind it
    points = d * _reference_ranges(d)[:, None]
    _, summary = lidar_agreement(scene, points, np.full(len(d), 255, np.uint8))
    assert summary.static_points == len(d) - on_car.sum() and summary.within == 1.0
    # the recording tags some of its points as a car our scene does not have there: left out too
    tags = np.full(len(d), TERRAIN, np.uint8)
    tags[:100] = CAR
    _, summary = lidar_agreement(scene, points, tags)
    assert summary.static_points == len(d) - (on_car | (np.arange(len(d)) < 100)).sum() and summary.within == 1.0
    # nothing static: the figures say so
    _, summary = lidar_agreement(scene, points, np.full(len(d), CAR, np.uint8))
    assert (summary.static_points, summary.median_m, summary.p95_m, summary.within) == (0, -1.0, -1.0, 0.0)
