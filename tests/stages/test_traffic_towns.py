"""No two actors interpenetrate on real towns: a procedural suburb crowded with walkers and CARLA's
Town10HD (short approach lanes before its junctions) with dense vehicles."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes import build_town, simulate_sequence
from carlaocc.stages.scenes.traffic.simulation import TRAFFIC_LEVELS, TrafficLevel, ego_starts

sys.path.insert(0, str(Path(__file__).parent))
from test_traffic import _boxes, _overlap  # noqa: E402
from shared_data import needs, shared_path  # noqa: E402

TOWN10 = shared_path("opendrive/Town10HD.xodr")


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


def _no_overlaps(res, lib) -> None:
    for f, boxes in _boxes(res, lib).items():
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                assert not _overlap(boxes[i][1], boxes[j][1]), f"frame {f}: {boxes[i][0]} overlaps {boxes[j][0]}"


@pytest.mark.slow  # `make test-all`; the default run builds every stage end to end elsewhere
def test_crowded_suburb_walkers(lib, monkeypatch):
    monkeypatch.setitem(TRAFFIC_LEVELS, "high", TrafficLevel(16.0, 40.0, 2.0, 0.4))
    cfg = ScenesConfig(frame_count=300, actor_range=1000.0)
    town = build_town(TownSpec(style="suburb"), cfg, 0, lib.assets)
    res = simulate_sequence(cfg, town, lib.assets, "high", 1, ego_starts(town, 2, cfg.seed)[1])
    assert res.walkers >= 50
    _no_overlaps(res, lib)


@needs(TOWN10)
def test_town10hd_dense_vehicles(lib, monkeypatch):
    from carlaocc.catalog.opendrive import read_opendrive

    monkeypatch.setitem(TRAFFIC_LEVELS, "high", TrafficLevel(40.0, 8.0, 2.0, 0.4))
    cfg = ScenesConfig(frame_count=250, actor_range=1000.0)
    town = build_town(TownSpec(style="opendrive", opendrive=str(TOWN10)), cfg, 0, lib.assets,
                      read_opendrive(TOWN10), str(TOWN10))
    res = simulate_sequence(cfg, town, lib.assets, "high", 0, ego_starts(town, 1, cfg.seed)[0])
    assert res.vehicles >= 30
    _no_overlaps(res, lib)
