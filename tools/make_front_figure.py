"""The front page's picture: one frame's front-camera RGB above its occupancy (the top view and
the 3D view of ``carlaocc show occupancy``, things coloured by instance), from a built root.

Usage: ``python tools/make_front_figure.py --root data --seq town00_high_seq000 --frame 1
--voxel-size 0.1 [--camera camera_00] [--out docs/front.png]`` after ``carlaocc run --res 0.1
--limit-frames 2`` (deterministic: the dataset's bytes decide the picture's).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from carlaocc.catalog.images import save_png  # noqa: E402
from carlaocc.catalog.occupancy import OccupancyStore  # noqa: E402
from carlaocc.catalog.sensors import SensorStore  # noqa: E402
from carlaocc.catalog.store import Store  # noqa: E402
from carlaocc.stages.render.figures import occupancy_figure  # noqa: E402
from carlaocc.stages.render.layout import Panel, compose  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="data")
    ap.add_argument("--seq", required=True)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--voxel-size", type=float, required=True)
    ap.add_argument("--camera", default="camera_00")
    ap.add_argument("--out", default="docs/front.png")
    a = ap.parse_args(argv)
    store = Store(a.root)
    sensors, occ = SensorStore(store), OccupancyStore(store)
    if not sensors.exists(a.seq, a.camera, "rgb"):
        raise SystemExit(f"error: {a.seq} in {a.root} has no {a.camera} rgb (run carlaocc run with sensors.rgb)")
    grid = occ.stored_grid(a.seq, a.voxel_size)
    if grid is None:
        raise SystemExit(f"error: {a.seq} in {a.root} has no occupancy at {a.voxel_size} m")
    rgb = sensors.read_image(a.seq, a.camera, a.frame, "rgb")
    data = occ.read_frame(a.seq, grid, a.frame, ("semantic", "instance"))
    views = occupancy_figure(data["semantic"], data["instance"], grid, f"occupancy at {grid.key} m", height=400).image
    sheet = compose([([Panel(f"{a.camera} RGB", rgb[:, :, :3])], None), ([Panel("", views)], None)],
                    title=f"{a.seq} frame {a.frame}")
    save_png(None, a.out, sheet.image)
    print(f"wrote {a.out} ({sheet.image.shape[1]}x{sheet.image.shape[0]})")


if __name__ == "__main__":
    main()
