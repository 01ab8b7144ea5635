"""Traffic follows the hills of an OpenDRIVE map (issue 38): the builtin crossroads laid over a
height field (``tools/make_hilly.py``: 8 m hills every 300 m, grades up to 16.8 %), once with
level cross sections as CARLA's towns have them and once banked to the field.

Expected poses come from the field itself, not from our road code: a vehicle's forward axis
climbs at the field's slope along its heading, its up axis is the banked road's normal."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from carlaocc.catalog.opendrive import parse_opendrive
from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes import build_town, simulate_sequence
from carlaocc.stages.scenes.opendrive.network import JOIN_STEP, JOIN_TOL, build_opendrive_network
from carlaocc.stages.scenes.traffic.simulation import TRAFFIC_LEVELS, TrafficLevel, ego_starts

REPO = Path(__file__).resolve().parents[2]
CROSSROADS = REPO / "catalog" / "towns" / "crossroads.xodr"
A, L = 8.0, 300.0  # m: hill height and wavelength (steepest grade 2 pi A / L = 16.8 %)


def _tool():
    spec = importlib.util.spec_from_file_location("make_hilly", REPO / "tools" / "make_hilly.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


HILLY = _tool()


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


def simulate(text: str, lib, monkeypatch, frames: int = 20):
    monkeypatch.setitem(TRAFFIC_LEVELS, "high", TrafficLevel(40.0, 8.0, 2.0, 0.4))
    cfg = ScenesConfig(frame_count=frames, actor_range=1000.0)
    odr = parse_opendrive(text, "hilly.xodr")
    town = build_town(TownSpec(style="opendrive", opendrive="hilly.xodr"), cfg, 0, lib.assets, odr, "hilly.xodr")
    return simulate_sequence(cfg, town, lib.assets, "high", 0, ego_starts(town, 1, cfg.seed)[0])


def vehicle_poses(res, lib):
    """(N, 4, 4) poses of every vehicle record and every frame's ego."""
    walkers = {a.asset_id for a in lib.assets if a.category == "Pedestrian"}
    poses = [a.pose for a in res.actors if a.asset_id not in walkers] + [f.ego_pose for f in res.frames]
    return np.array(poses, dtype=float).reshape(-1, 4, 4)


def field_slope(P, amplitude: float = A):
    """The field's slope along each pose's heading, and its upward unit normal, at the pose."""
    x, y = P[:, 0, 3], P[:, 1, 3]
    gx, gy = HILLY.field_gradient(x, y, amplitude, L)
    hx, hy = P[:, 0, 0], P[:, 1, 0]
    n = np.hypot(hx, hy)
    normal = np.column_stack([-gx, -gy, np.ones_like(gx)])
    return (gx * hx + gy * hy) / n, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def test_level_cross_sections_keep_their_junctions():
    """Level cross sections on a slope: connectors meet the incoming lanes with a vertical step
    (up to a few decimetres); the links are kept (the lane graph was cut to nothing before)."""
    text = HILLY.hilly_xodr(CROSSROADS.read_text(), A, L)
    net, stats = build_opendrive_network(parse_opendrive(text), 0.15)
    flat, flat_stats = build_opendrive_network(parse_opendrive(CROSSROADS.read_text()), 0.15)
    assert stats["link_mismatches"] == 0 and stats["scc_dropped"] == 0
    assert stats["link_steps"] > 0 and JOIN_TOL < stats["step_max"] <= JOIN_STEP
    assert len(net.lanes) == len(flat.lanes) and flat_stats["link_steps"] == 0


def test_vehicles_pitch_with_the_hills(lib, monkeypatch):
    """Level cross sections: every vehicle and the ego climb at the road's slope under them
    (within 1 degree), stand level across it, and traffic is spread over the hills."""
    res = simulate(HILLY.hilly_xodr(CROSSROADS.read_text(), A, L), lib, monkeypatch)
    P = vehicle_poses(res, lib)
    slope, _ = field_slope(P)
    climb = np.degrees(np.arcsin(np.clip(P[:, 2, 0], -1, 1)))  # forward axis above the horizontal
    err = np.abs(climb - np.degrees(np.arctan(slope)))
    assert res.vehicles >= 10 and len(P) >= 200
    print(f"\npitch error (deg): median {np.median(err):.3f}, max {err.max():.3f} over {len(P)} poses")
    assert err.max() < 1.0, f"pitch off the road's slope by up to {err.max():.2f} deg"
    print(f"poses on slopes over 5 %: {np.mean(np.abs(slope) > 0.05):.1%} (58 % of the lane length)")
    assert np.mean(np.abs(slope) > 0.05) > 0.3  # spawned on the hills, not only on the flat
    assert np.abs(climb).max() > 5.0
    # level cross section: the body's y axis stays horizontal
    assert np.abs(P[:, 2, 1]).max() < math.sin(math.radians(1.0))


def test_vehicles_bank_with_the_road(lib, monkeypatch):
    """Banked to the field: every vehicle's and the ego's up axis is the field's normal (within 1
    degree). Half the hill height: the bank is the field's cross slope at the reference line, which
    differs from the field's at a lane 5 m beside it by about ``A (2 pi / L)^2 5 m`` (0.5 degree here)."""
    res = simulate(HILLY.hilly_xodr(CROSSROADS.read_text(), A / 2, L, bank=True), lib, monkeypatch)
    P = vehicle_poses(res, lib)
    slope, normal = field_slope(P, A / 2)
    tilt = np.degrees(np.arccos(np.clip(np.sum(P[:, :3, 2] * normal, axis=1), -1, 1)))
    print(f"\nup-axis error (deg): median {np.median(tilt):.3f}, max {tilt.max():.3f} over {len(P)} poses")
    assert tilt.max() < 1.0, f"up axis off the road's normal by up to {tilt.max():.2f} deg"
    roll_expected = np.degrees(np.arccos(np.clip(normal[:, 2], -1, 1)))
    assert roll_expected.max() > 3.0  # the test is not trivially level
