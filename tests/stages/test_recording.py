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
