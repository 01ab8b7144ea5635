"""Scenes stage: towns (procedural styles and OpenDRIVE), traffic sequences driven through them,
and per-frame panoptic scene meshes in the LiDAR frame."""

from __future__ import annotations

from collections.abc import Sequence

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town, Walkway, check_network
from carlaocc.stages.scenes.traffic import TRAFFIC_LEVELS, SequenceResult, ego_starts, simulate_sequence, simulate_town

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
        from carlaocc.stages.scenes.odr_town import build_opendrive_town

        return build_opendrive_town(opendrive, spec, scenes, index, assets, source)
    from carlaocc.stages.scenes.town import build_procedural_town

    return build_procedural_town(spec, scenes, index, assets)
