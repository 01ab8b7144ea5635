"""Scenes stage: towns (procedural styles and OpenDRIVE), traffic sequences driven through them,
and per-frame panoptic scene meshes in the LiDAR frame. :func:`build_town` builds a town of either
kind; :func:`simulate_town` drives its sequences.

* ``network``    — the town contract: lanes, walkways, road network, town
* ``placing``    — shared by town builders: stuff slabs, placement records, asset pools
* ``town/``      — procedural towns (downtown, suburb, arterial): plan, roads, walkways, buildings, furniture
* ``opendrive/`` — OpenDRIVE towns: geometry, ground surfaces, lane and walk graphs, the driver
* ``recording``  — recorded towns and sequences (CARLA recordings) on the same contract
* ``traffic/``   — traffic sequences: levels, spawning, integration, vehicles, walkers, junctions
* ``people/``    — pedestrians posed by gait-phase matching; the gait analysis; skeleton rows
* ``assembly``   — per-frame panoptic scene assembly; the town's static mesh
"""

from __future__ import annotations

from collections.abc import Sequence

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town, Walkway, check_network
from carlaocc.stages.scenes.opendrive.town import build_opendrive_town
from carlaocc.stages.scenes.town.build import build_procedural_town
from carlaocc.stages.scenes.traffic.simulation import (
    TRAFFIC_LEVELS, SequenceResult, ego_starts, simulate_sequence, simulate_town,
)

__all__ = [
    "Lane", "RoadNetwork", "SequenceResult", "TRAFFIC_LEVELS", "Town", "Walkway", "build_town", "check_network",
    "ego_starts", "simulate_sequence", "simulate_town",
]  # fmt: skip


def build_town(
    spec: TownSpec, scenes: ScenesConfig, index: int, assets: Sequence[AssetRecord], opendrive=None, source: str = ""
) -> Town:
    """Town ``index`` of the dataset from its spec: a procedural style, or -- for the opendrive
    style -- the parsed OpenDRIVE network ``opendrive`` read from ``source``."""
    if spec.style == "opendrive":
        if opendrive is None:
            raise ValueError(f"town {index}: the opendrive style needs the parsed network of {spec.opendrive}")
        return build_opendrive_town(opendrive, spec, scenes, index, assets, source)
    return build_procedural_town(spec, scenes, index, assets)
