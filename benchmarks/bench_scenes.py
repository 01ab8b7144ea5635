"""Scenes throughput, in one run: seconds to read an OpenDRIVE town and build its road surfaces
(the builtin town and, when the shared test data is present, CARLA's Town01 and Town10HD),
placements per second of town building (each procedural style, the builtin OpenDRIVE town and
Town10HD), frames per second of traffic simulation (high traffic, with and without the Skeletal
Motion Analyzer's phase matching), and frames per second of per-frame panoptic assembly
(placement index selection, actors, posed pedestrians) for the default occupancy region and for
an 80 m sensor range.

Usage: ``python -m benchmarks.bench_scenes [FRAMES]`` (default 200 simulated frames).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

OPENDRIVE_DATA = Path(__file__).resolve().parents[2] / "shared" / "testdata" / "opendrive"
TOWN10 = OPENDRIVE_DATA / "Town10HD.xodr"


def _best(fn, repeat: int = 3) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _road_surfaces() -> None:
    """Seconds to read an ``.xodr`` file and build the surface meshes of all its roads (0.5 m)."""
    from carlaocc.catalog.opendrive import read_opendrive
    from carlaocc.catalog.towns import resolve_opendrive
    from carlaocc.stages.scenes.opendrive.geometry import road_surface_meshes

    paths = [resolve_opendrive("builtin:crossroads.xodr")]
    paths += [p for p in (OPENDRIVE_DATA / "Town01.xodr", TOWN10) if p.exists()]
    print("\nOpenDRIVE road surfaces, read + meshes of every road at 0.5 m (best of 3)")
    print(f"{'town':>18} {'roads':>6} {'triangles':>10} {'seconds':>8}")
    for path in paths:
        def build(path=path):
            net = read_opendrive(path)
            return net, [road_surface_meshes(r, step=0.5) for r in net.roads]

        t, (net, parts) = _best(build)
        tris = sum(len(f) for m in parts for _v, f in m.values())
        print(f"{path.name:>18} {len(net.roads):>6} {tris:>10,} {t:>8.3f}")


def main(argv: list[str] | None = None) -> None:
    from carlaocc.catalog.opendrive import read_opendrive
    from carlaocc.catalog.towns import resolve_opendrive
    from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
    from carlaocc.schemas.grid import GridSpec
    from carlaocc.stages.ingest import ingest_procedural
    from carlaocc.stages.scenes import build_town, simulate_sequence
    from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame, region_of_grid
    from carlaocc.stages.scenes.people.pedestrians import match_walker_phases, rig_pedestrian
    from carlaocc.stages.scenes.traffic.simulation import ego_starts

    argv = sys.argv[1:] if argv is None else argv
    frames = int(argv[0]) if argv else 200
    lib = ingest_procedural(IngestConfig())
    scenes = ScenesConfig()
    print(f"{len(lib.assets)} procedural assets")
    _road_surfaces()

    # 1. town building
    towns = {}
    specs = [(s, TownSpec(style=s), None, "") for s in ("downtown", "suburb", "arterial")]
    for ref in ("builtin:crossroads.xodr", str(TOWN10) if TOWN10.exists() else None):
        if ref is None:
            continue
        path = resolve_opendrive(ref)
        specs.append((path.name, TownSpec(style="opendrive", opendrive=ref), read_opendrive(path), ref))
    print("\ntown building (best of 3)")
    print(f"{'town':>18} {'placements':>10} {'lanes':>6} {'road km':>8} {'seconds':>8} {'placements/s':>13}")
    for name, spec, odr, ref in specs:
        t, town = _best(lambda: build_town(spec, scenes, 0, lib.assets, odr, ref))
        towns[name] = town
        n = len(town.placements)
        print(f"{name:>18} {n:>10} {len(town.network.lanes):>6} {town.network.road_length / 1000:>8.2f} "
              f"{t:>8.3f} {n / t:>13.0f}")

    # 2. traffic simulation (the default town styles at the high level)
    cfg = ScenesConfig(frame_count=frames)
    print(f"\ntraffic simulation, level high, {frames} frames at 20 Hz")
    print(f"{'town':>18} {'vehicles':>8} {'walkers':>7} {'lane chg':>8} {'fps':>8} {'fps+phase':>10}")
    results = {}
    for name in ("downtown", "arterial", "crossroads.xodr"):
        town = towns[name]
        start = ego_starts(town, 1, cfg.seed)[0]
        t0 = time.perf_counter()
        res = simulate_sequence(cfg, town, lib.assets, "high", 0, start)
        t_sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = simulate_sequence(cfg, town, lib.assets, "high", 0, start, match_phases=match_walker_phases)
        t_phase = time.perf_counter() - t0
        results[name] = res
        print(f"{name:>18} {res.vehicles:>8} {res.walkers:>7} {res.lane_changes:>8} {frames / t_sim:>8.0f} "
              f"{frames / t_phase:>10.0f}")

    # 3. per-frame assembly on the downtown town's sequence
    town, res = towns["downtown"], results["downtown"]
    geometry = {**lib.geometry, **town.stuff}
    rigs: dict[str, object] = {}

    def posed(asset_id: str, phase: int):
        if asset_id not in rigs:
            rigs[asset_id] = rig_pedestrian(geometry[asset_id])
        return rigs[asset_id].posed(phase)

    regions = {"occupancy region": region_of_grid(GridSpec(voxel_size=0.2)),
               "80 m sensor range": (np.array([-80.0, -80.0, -5.0]), np.array([80.0, 80.0, 20.0]))}
    index_t, index = _best(lambda: PlacementIndex(town.placements))
    print(f"\nper-frame assembly, downtown ({len(town.placements)} placements; index built in {index_t * 1e3:.1f} ms)")
    print(f"{'region':>18} {'meshes':>7} {'triangles':>10} {'fps':>8}")
    n_frames = min(40, len(res.frames))
    for label, region in regions.items():
        def run():
            out = None
            for f in res.frames[:n_frames]:
                actors = [a for a in res.actors if a.frame_index == f.frame_index]
                out = assemble_frame(f, actors, index, geometry, region, posed, res.sequence.ego_asset_id)
            return out

        t, scene = _best(run, repeat=2)
        tris = sum(len(m.faces) for m in scene)
        print(f"{label:>18} {len(scene):>7} {tris:>10,} {n_frames / t:>8.1f}")


if __name__ == "__main__":
    main()
