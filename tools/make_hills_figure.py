"""The picture of full poses in docs/concepts/scenes.md: cars pitched on the crest and rolled on a banked curve of
the builtin hills town (``catalog/towns/hills.xodr``).

Builds, in memory and with the pipeline's own code, the procedural ADMesh library, the hills town
and a dense traffic sequence on it (the scenes stage's ``build_town`` / ``simulate_sequence``),
picks the most pitched and the most rolled car of the first frame, assembles each one's
surroundings in a world-aligned grid (``assemble_frame`` with an identity LiDAR pose) and
voxelizes it at 0.1 m (``voxelize_scene``, elevation order along world z). Level orthographic
views with axes in metres (along or across the car from its centre; world height) and a legend of
the classes: the pitched car seen from its side, the rolled car from behind, as recorded (bottom
row) and, for comparison, with its yaw alone (top row: the same car sinks into the road and floats
beside it).

Usage: ``python tools/make_hills_figure.py [--out docs/hills.png]`` (deterministic: the same
bytes every run on the same code).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from carlaocc.catalog.images import save_png  # noqa: E402
from carlaocc.catalog.opendrive import read_opendrive  # noqa: E402
from carlaocc.catalog.towns import resolve_opendrive  # noqa: E402
from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec  # noqa: E402
from carlaocc.schemas.grid import GridSpec  # noqa: E402
from carlaocc.schemas.records import FrameRecord  # noqa: E402
from carlaocc.stages.geometry import pose_from_list, pose_matrix, pose_to_list  # noqa: E402
from carlaocc.stages.ingest import ingest_procedural  # noqa: E402
from carlaocc.stages.render.figures import class_entries  # noqa: E402
from carlaocc.stages.render.layout import Key, Panel, compose  # noqa: E402
from carlaocc.stages.render.occupancy import orthographic_extent, perspective_view  # noqa: E402
from carlaocc.stages.scenes import build_town, simulate_sequence  # noqa: E402
from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame  # noqa: E402
from carlaocc.stages.scenes.traffic.simulation import ego_starts  # noqa: E402
from carlaocc.stages.voxelize import voxelize_scene  # noqa: E402

VOXEL = 0.1  # m
PANEL = (360, 640)  # px, height x width of each view


def _view(town, geometry, frame, actor, azimuth_deg: float, across: bool):
    """A 0.1 m world-aligned voxel view of ``actor``'s surroundings (9 x 9 x 6 m around it),
    orthographic, level (elevation 0: screen up is world z), looking from ``azimuth_deg``
    relative to the car's heading. Returns the image, the semantic grid and the panel's extent
    in metres: the horizontal axis along the car's heading (forward +) for a side view, across
    it (its left +) for a view from behind, measured from the car's centre; the vertical axis
    world z."""
    centre = pose_from_list(actor.pose)[:3, 3]
    lo, hi = centre - [4.5, 4.5, 2.0], centre + [4.5, 4.5, 4.0]
    world = FrameRecord(sequence_id=frame.sequence_id, frame_index=frame.frame_index, timestamp=frame.timestamp,
                        ego_pose=frame.ego_pose, lidar_pose=pose_to_list(np.eye(4)))  # fmt: skip
    scene = assemble_frame(world, [actor], PlacementIndex(town.placements), geometry, (lo, hi))
    grid = GridSpec(region_min=tuple(lo), region_max=tuple(hi), voxel_size=VOXEL)
    semantic, instance = voxelize_scene(scene, grid)
    az = math.degrees(actor.yaw) + azimuth_deg
    bounds = tuple(zip(lo, hi))
    img = perspective_view(semantic, instance, grid, size=PANEL, elevation_deg=0.0, azimuth_deg=az,
                           mode="semantic", fov_deg=0.0, bounds=bounds)  # fmt: skip
    left, right, bottom, top = orthographic_extent(bounds, PANEL, 0.0, az)
    # screen right is the car's rear (side view) or its right (view from behind): negate it to
    # read forward + / left +; heights from the bounds' centre to world z
    zc = (lo[2] + hi[2]) / 2
    return img, semantic, (-left, -right, zc + bottom, zc + top)


def hills_figure() -> np.ndarray:
    lib = ingest_procedural(IngestConfig())
    path = resolve_opendrive("builtin:hills.xodr")
    cfg = ScenesConfig(frame_count=2, actor_range=1000.0)
    town = build_town(TownSpec(style="opendrive", opendrive=str(path), traffic_levels=("high",)), cfg, 0,
                      lib.assets, read_opendrive(path), str(path))  # fmt: skip
    res = simulate_sequence(cfg, town, lib.assets, "high", 0, ego_starts(town, 1, cfg.seed)[0])
    cars = {a.asset_id for a in lib.assets if a.category == "Car"}
    first = [a for a in res.actors if a.frame_index == 0 and a.asset_id in cars]
    pitched = max(first, key=lambda a: abs(a.pitch))
    rolled = max(first, key=lambda a: abs(a.roll))
    geometry = {**lib.geometry, **town.stuff}
    rows, grids = [], []
    for full in (False, True):
        panels = []
        for actor, azimuth, label in ((pitched, 90.0, "pitch"), (rolled, 180.0, "roll")):
            shown = actor
            if not full:  # the same car with its yaw alone
                T = pose_from_list(actor.pose)
                shown = actor.model_copy(update={"pose": pose_to_list(pose_matrix(*T[:3, 3], actor.yaw))})
            img, semantic, extent = _view(town, geometry, res.frames[0], shown, azimuth, label == "roll")
            grids.append(semantic)
            title = (f"car {actor.instance_id}, {label} {math.degrees(getattr(actor, label)):+.1f} deg: "
                     + ("full pose" if full else "yaw only"))
            xlabel = ("seen from its left side: along the car, m (forward +)" if label == "pitch"
                      else "seen from behind: across the car, m (its left +)")
            panels.append(Panel(title, img, extent, xlabel, "height, m (world z)"))
        rows.append(panels)
    entries = class_entries(np.concatenate([g.ravel() for g in grids]), None, "semantic")
    key = Key(f"colour: class ({VOXEL:g} m voxels)", tuple(entries))
    sheet = compose([(rows[0], key), (rows[1], None)],
                    title="Full poses on the hills town: the most pitched and the most rolled car of frame 0")
    return sheet.image


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="docs/hills.png", help="PNG to write (default: docs/hills.png)")
    args = parser.parse_args()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    save_png(None, args.out, hills_figure())
    print(f"wrote {args.out}")
