"""The viewer's pictures in the manual (docs/viewer.png, docs/viewer_pred.png): ``carlaocc view``
served on loopback and photographed in headless Chromium (tools/headless_chromium.py).

    python tools/make_viewer_figure.py --root R [--voxel-size 0.2] [--pred DIR] [--colour semantic]
                                       [--out docs/viewer.png]
    python tools/make_viewer_figure.py --pred P --gt G [--map occ3d] [--root R] [--out docs/viewer_pred.png]

docs/viewer.png: ``carlaocc run --root R --voxel-size 0.2 --limit-frames 3 --sequences
town00_high_seq000``, frame 0, classes; docs/viewer_pred.png: ``--pred`` a tree made from the
root's Occ3D export with errors against that export (``--gt``, ``--map occ3d``; the tutorial
docs/tutorials/viewer.md says how).
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
import headless_chromium  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root")
    ap.add_argument("--gt", type=Path)
    ap.add_argument("--map", default="carlaocc")
    ap.add_argument("--voxel-size", type=float, default=0.2)
    ap.add_argument("--pred", type=Path)
    ap.add_argument("--colour", default=None, help="semantic | instance | outcome (default: outcome with --pred)")
    ap.add_argument("--out", type=Path, default=Path("docs/viewer.png"))
    ap.add_argument("--size", default="1280x760")
    args = ap.parse_args()
    from carlaocc.pipeline.commands.viewer import (RootFrames, Viewer, open_frames, prediction_files,
                                                    start_server, stop_server)
    from carlaocc.pipeline.commands.viewer_pairs import pair_frames

    exe = headless_chromium.find_chromium()
    if exe is None:
        sys.exit("error: no Chromium on PATH: sh tools/setup_system.sh --test")
    if args.gt is not None:
        source = pair_frames(args.pred, args.gt, args.map)
        if args.root:
            source = source.with_root(args.root)
    else:
        samples = open_frames(args.root, None, args.voxel_size)
        preds = None
        if args.pred is not None:
            preds = prediction_files(args.pred, samples.samples[0][0], [f for _, f in samples.samples])
        source = RootFrames(samples, preds)
    width, height = (int(v) for v in args.size.split("x"))
    server = start_server()
    try:
        viewer = Viewer(server, source, 400_000)
        if args.colour:
            viewer.mode.value = args.colour
            viewer.draw()
        with headless_chromium.Browser(exe, width, height) as browser:
            page = browser.open(f"http://127.0.0.1:{server.get_port()}")
            page.wait_for("document.querySelector('canvas') !== null", 120)
            # dismiss the software-rendering notice, then wait until two screenshots agree
            time.sleep(3)
            page.eval("document.querySelectorAll('.mantine-Notification-closeButton').forEach(b => b.click())")
            last = None
            for _ in range(60):
                time.sleep(1.0)
                png = page.screenshot()
                img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
                if last is not None and np.array_equal(img, last) and img.std() > 20:
                    break
                last = img
    finally:
        stop_server(server)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.open(io.BytesIO(png)).save(args.out, optimize=True)
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
