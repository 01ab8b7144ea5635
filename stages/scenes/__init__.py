"""Scenes stage: towns (procedural styles and OpenDRIVE), traffic sequences driven through them,
and per-frame panoptic scene meshes in the LiDAR frame. :func:`build_town` builds a town of either
kind; :func:`simulate_town` drives its sequences.

* ``network``           — the town contract: lanes, walkways, road network, town
* ``placing``           — shared by town builders: stuff slabs, placement records, asset pools
* ``town``              — procedural towns (downtown, suburb, arterial): the driver
* ``town_layout``       — a procedural town's plan: styles, cross-sections, grid, the draft
* ``town_geometry``     — plan geometry: polylines, extruded slabs, polygon tests, footprints
* ``town_roads``        — carriageways, medians, road markings and the lane graph
* ``town_walkways``     — sidewalks, kerbs, block grounds and lots, outer ring, walk graph
* ``town_buildings``    — buildings in the lots and their frontages (fences, hedges, walls)
* ``town_furniture``    — junction control, lights and signs, street furniture, parked cars, trees
* ``opendrive``         — OpenDRIVE geometry: reference lines, lane boundaries, surface meshes
* ``odr_surfaces``      — an OpenDRIVE town's ground: lane surfaces, road marks, raster, terrain
* ``odr_network``       — an OpenDRIVE town's lane graph and walk graph
* ``odr_town``          — OpenDRIVE towns: the driver, signals, buildings, vegetation
* ``traffic``           — traffic sequences: levels, spawning, integration, records
* ``traffic_vehicles``  — vehicles: IDM, leaders along the lanes, lane changes
* ``traffic_walkers``   — walkers on the walk graph, gait phase
* ``traffic_junctions`` — junction reservations shared by vehicles and walkers
* ``gait/``             — the Skeletal Motion Analyzer: gait-phase matching of walkers
* ``pedestrians``       — pedestrians posed by gait-phase matching
* ``assembly``          — per-frame panoptic scene assembly; the town's static mesh
"""

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
