"""The six-camera RGB sheet of docs/concepts/sensors.md: one frame of a built dataset's rendered (or recorded) RGB,
the rig's cameras in two rows of three (``camera_00`` .. ``camera_05``: front stereo pair, left,
right, rear stereo pair; docs/architecture.md "Reference rig"), each halved in size, titled with
its name and the direction it faces (the root's rig).

Usage: ``python tools/make_rgb_sheet.py --root data --seq town00_high_seq000 --frame 10
[--out docs/rgb_sheet.png]`` after ``make dataset RES=0.2`` (deterministic: the dataset's
bytes decide the picture's).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from carlaocc.catalog.images import save_png  # noqa: E402
from carlaocc.catalog.sensors import SensorStore  # noqa: E402
from carlaocc.catalog.store import Store  # noqa: E402
from carlaocc.pipeline.cli.common import load_config  # noqa: E402
from carlaocc.schemas.rig import camera_roles  # noqa: E402
from carlaocc.stages.render.layout import Panel, compose  # noqa: E402


def sheet(images: dict[str, np.ndarray], roles: dict[str, str], title: str, columns: int = 3) -> np.ndarray:
    """The images (H x W x 3 uint8), halved, in rows of ``columns``, each titled with its camera
    and role."""
    names = sorted(images)
    panels = [Panel(f"{n} ({roles[n]})" if n in roles else n, np.ascontiguousarray(images[n][::2, ::2, :3]))
              for n in names]
    return compose([(panels[k : k + columns], None) for k in range(0, len(panels), columns)], title=title).image


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="data")
    ap.add_argument("--seq", required=True)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--out", default="docs/rgb_sheet.png")
    a = ap.parse_args(argv)
    sensors = SensorStore(Store(a.root))
    cams = [c for c in sensors.cameras(a.seq) if sensors.exists(a.seq, c, "rgb")]
    if not cams:
        raise SystemExit(f"error: {a.seq} in {a.root} has no rgb images (run carlaocc run with sensors.rgb)")
    roles = camera_roles(load_config(None, a.root).scenes.rig.cameras)
    images = {c: sensors.read_image(a.seq, c, a.frame, "rgb") for c in cams}
    save_png(None, a.out, sheet(images, roles, f"{a.seq} frame {a.frame}: RGB (every 2nd pixel)"))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
