"""The README's six-camera RGB contact sheet: one frame of a built dataset's rendered (or
recorded) RGB, the rig's cameras in two rows of three (front-left, front-right, left / right,
rear-left, rear-right: ``camera_00`` .. ``camera_05``), each halved in size, named in a strip.

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
from carlaocc.stages.render.sheets import FONT_HEIGHT, draw_text  # noqa: E402


def sheet(images: dict[str, np.ndarray], columns: int = 3, gap: int = 4) -> np.ndarray:
    """The images (H x W x 3 uint8, same size), halved, in rows of ``columns``, each named above."""
    names = sorted(images)
    half = {n: images[n][::2, ::2] for n in names}
    h, w, _ = half[names[0]].shape
    strip = 2 * FONT_HEIGHT + 6
    rows = (len(names) + columns - 1) // columns
    out = np.full((rows * (h + strip + gap), columns * (w + gap), 3), 255, np.uint8)
    for k, n in enumerate(names):
        y, x = (k // columns) * (h + strip + gap), (k % columns) * (w + gap)
        draw_text(out, n, x + 3, y + 3, (0, 0, 0), 2)
        out[y + strip:y + strip + h, x:x + w] = half[n]
    return out


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
    save_png(None, a.out, sheet({c: sensors.read_image(a.seq, c, a.frame, "rgb") for c in cams}))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
