"""Recorded sequences: the walk-cycle phase matcher on the gait signal (left knee ahead of the
right), against a brute-force truth; recorded towns on the town contract."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas import taxonomy
from carlaocc.stages.scenes.recording import match_walk_frames, recorded_town, traffic_level_of

K = 36
# a gait signal with a second harmonic (a real stride is not a pure sine), in centimetres
CYCLE = 30 * np.sin(2 * np.pi * np.arange(K) / K) + 3 * np.cos(4 * np.pi * np.arange(K) / K)


def _signal(phase: np.ndarray, gain: float) -> np.ndarray:
    x = np.mod(phase, 1.0) * K
    i = np.floor(x).astype(int) % K
    w = x - np.floor(x)
    return (CYCLE[i] * (1 - w) + CYCLE[(i + 1) % K] * w) * gain


@settings(max_examples=40, deadline=None)
@given(frames=st.integers(5, 120), rate=st.floats(0.5, 2.5), start=st.floats(0, 1), gain=st.floats(1e-3, 0.05))
def test_the_matched_frame_is_the_true_phase(frames, rate, start, gain):
    # the recorded signal is the cycle's at a constant gait rate, in metres (any gain), at 10 Hz
    t = np.arange(frames) / 10.0
    true = (start + rate * t) % 1.0
    matched = match_walk_frames(_signal(true, gain), t, CYCLE)
    err = np.abs((matched / K - true + 0.5) % 1.0 - 0.5) * K  # in cycle frames
    assert err.max() <= 1.5


def test_a_leg_swinging_back_is_not_one_swinging_forward():
    # the same values on the rising and the falling side of the signal: only time tells them apart
    t = np.arange(12) / 10.0
    rising, falling = (0.9 + 1.0 * t) % 1.0, (0.4 + 1.0 * t) % 1.0
    a = match_walk_frames(_signal(rising, 0.01), t, CYCLE)
    b = match_walk_frames(_signal(falling, 0.01), t, CYCLE)
    assert np.abs((a - b + K // 2) % K - K // 2).min() >= K // 2 - 2


def test_traffic_levels_follow_the_collection_protocol():
    assert [traffic_level_of(i) for i in (0, 1, 3, 4, 6, 7, 12)] == ["none", "low", "low", "medium", "medium",
                                                                      "high", "high"]  # fmt: skip


def test_a_recorded_town_places_every_static_mesh():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    # a road (stuff), a building (stuff in the release's table) and a pole (a thing there: numbered)
    statics = [("Road_1", 1, V, F), ("House_1", 3, V + [5, 0, 0], F), ("Pole_1", 6, V + [2, 0, 0], F)]
    town = recorded_town("town03", 3, "rec", statics)
    assert town.style == "carla-recording" and sorted(town.stuff) == ["town03/House_1", "town03/Pole_1", "town03/Road_1"]
    by_name = {p.name: p for p in town.placements}
    assert [by_name[n].instance_id for n in ("Road_1", "House_1", "Pole_1")] == [0, 0, 1] and town.max_instance_id == 1
    # under carlaocc-v1 the building is the thing
    v1 = recorded_town("town03", 3, "rec", statics, frozenset(taxonomy.thing_ids("carlaocc-v1")))
    assert [p.instance_id for p in v1.placements] == [0, 1, 0]
    assert town.bounds == (0.0, 0.0, 6.0, 1.0)
    with pytest.raises(ValueError, match="no static actor"):
        recorded_town("town03", 3, "rec", [])


def _walk_tool():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "make_carla_recording", Path(__file__).resolve().parents[2] / "tools" / "make_carla_recording.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("height", [1.2, 1.62, 1.8, 1.95])
def test_a_recorded_walker_is_as_tall_as_its_box(height):
    """The walk cycle (1.8 m tall, feet at its origin) is scaled to each walker's recorded box:
    in every frame the posed mesh's top is the box's top within 1 mm (the scale is rounded to
    4 decimals: 0.2 mm at 2 m) and its lowest point is the cycle frame's own lowest point, scaled,
    above the box's bottom (the feet stand on it)."""
    from carlaocc.catalog.carla_recording import EgoState, PedestrianState, TrafficFrame
    from carlaocc.schemas.meshes import AssetGeometry, MeshPart
    from carlaocc.schemas.records import AssetRecord
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.geometry import transform_points
    from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame
    from carlaocc.stages.scenes.recording import (RecordedFrame, WalkFrame, cycle_height, recorded_sequence,
                                                  translation)

    tool = _walk_tool()
    cycle, geometry, lows = [], {}, []
    for i in range(0, 36, 6):  # six frames of the tool's walk cycle, in the actor axes with the feet at z = 0
        V, F, _ = tool.walker_pose(i / 36)
        lo, hi = V.min(axis=0), V.max(axis=0)
        off = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])  # the asset origin: bottom centre
        aid = f"walk{i:02d}"
        asset = AssetRecord(asset_id=aid, source="carla-recording", source_path=aid, licence="x", category_id=12,
                            category="Pedestrian", subclass="adult", extent=list(hi - lo), vertex_count=len(V),
                            face_count=len(F), part_count=1, transparent_part_count=0, surface_area=1.0, volume=1.0,
                            watertight=True, geometry_hash=aid, mesh_path="")
        geometry[aid] = AssetGeometry(aid, (MeshPart("body", V - off, F, 12),), (True,))
        cycle.append(WalkFrame(asset=asset, offset=off, stride=float(np.sin(2 * np.pi * i / 36))))
        lows.append(lo[2])
    assert cycle_height(cycle) == pytest.approx(1.8)
    town = recorded_town("town00", 0, "rec", [("Road", 1, np.array([[-50.0, -50, 0], [50, -50, 0], [0, 50, 0]]),
                                                np.array([[0, 1, 2]]))])  # fmt: skip
    geometry.update(town.stuff)
    frames = []
    for k in range(6):
        walker = translation(3.0 + 0.14 * k, 4.0, 0.3 + height / 2) @ np.diag([-1.0, -1.0, 1.0, 1.0])  # turned 180 deg
        ped = PedestrianState(id=301, type="walker.pedestrian.0001", transform=walker,
                              extent=np.array([0.25, 0.25, height / 2]), bones={})
        traffic = TrafficFrame(ego=EgoState(1, "vehicle.x", None, None, None), vehicles=(), pedestrians=(ped,))
        frames.append(RecordedFrame(number=k, lidar_pose=translation(0.0, 0.0, 1.73 + 0.02 * k), traffic=traffic))
    seq = recorded_sequence("town00_s", town, 0, frames, RigConfig(), {}, cycle)
    index = PlacementIndex(town.placements)
    for k, fr in enumerate(seq.frames):
        (actor,) = [a for a in seq.actors if a.frame_index == k]
        assert actor.scale == pytest.approx(height / 1.8, abs=1e-4) and actor.box_size[2] == pytest.approx(height)
        scene = assemble_frame(fr, seq.actors, index, geometry, (np.full(3, -60.0), np.full(3, 60.0)))
        (mesh,) = [m for m in scene if m.instance_id == actor.instance_id]
        z = transform_points(np.asarray(fr.lidar_pose).reshape(4, 4), mesh.vertices)[:, 2]
        bottom, top = 0.3, 0.3 + height  # the recorded box, world z
        assert z.max() == pytest.approx(top, abs=1e-3)
        j = round(actor.gait_phase * len(cycle))
        assert z.min() == pytest.approx(bottom + actor.scale * lows[j], abs=1e-3)
