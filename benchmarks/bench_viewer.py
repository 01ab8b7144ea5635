"""``carlaocc view`` speed, server and client, at each voxel size of a root, no thresholds:

* server: reading and preparing one frame (:func:`carlaocc.pipeline.commands.viewer.prepare_frame`:
  the surface voxels read chunk by chunk, level of detail, overlays, camera thumbnails), s of
  wall clock and of this process's CPU (the second does not grow with the machine's load);
* client, in headless Chromium (WebGL on SwiftShader, the CPU; tools/headless_chromium.py):
  time to first picture (page opened until the frame's largest class covers 300 canvas pixels)
  and frame switch (the server draws the next, already prepared frame until the canvas changes
  on 2 % of its pixels), s. Both are polled by screenshots, so they are bounded below by one
  screenshot's time, printed too.

Usage: ``python -m benchmarks.bench_viewer [--root R] [--voxel-sizes 0.2,0.05] [--budget 400000]``
(without ``--root``: builds the first 2 frames of ``town00_high_seq000`` at those sizes into a
temporary root first, printing its time).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import headless_chromium  # noqa: E402

from carlaocc.pipeline.commands.viewer import (DEFAULT_BUDGET, RootFrames, Viewer, open_frames, prepare_frame,  # noqa: E402
                                                start_server, stop_server)
from carlaocc.schemas.taxonomy import palette  # noqa: E402


def _canvas(page) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(np.int16)


def measure(root: str, voxel_size: float, budget: int, switches: int = 3) -> dict:
    samples = open_frames(root, None, voxel_size)
    n = len(samples)
    prepare_frame(samples, 0, None, budget)  # numba's kernels loaded, the tables read: as in a running viewer
    prep, cpu = [], []
    for k in range(n):
        c = time.process_time()
        prep.append(prepare_frame(samples, k, None, budget))
        cpu.append(time.process_time() - c)
    out = {"voxel_size": voxel_size, "frames": n, "occupied": int(np.mean([v.occupied for v in prep])),
           "drawn": int(np.mean([len(v.centres) for v in prep])), "point_size": prep[0].point_size,
           "prepare_s": float(np.mean([v.seconds for v in prep])), "prepare_cpu_s": float(np.mean(cpu))}
    server = start_server()
    try:
        viewer = Viewer(server, RootFrames(samples), budget, prepared=dict(enumerate(prep)))
        ids, counts = np.unique(prep[0].semantic, return_counts=True)
        colour = np.array(palette()[int(ids[np.argmax(counts)])])
        with headless_chromium.Browser(headless_chromium.find_chromium(), 1280, 800) as browser:
            t0 = time.perf_counter()
            page = browser.open(f"http://127.0.0.1:{server.get_port()}")
            while True:
                img = _canvas(page)
                if int((np.abs(img - colour).max(-1) <= 4).sum()) >= 300 or time.perf_counter() - t0 > 600:
                    break
            out["first_picture_s"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            _canvas(page)
            out["screenshot_s"] = time.perf_counter() - t1
            times = []
            for s in range(switches):
                before = _canvas(page)
                t = time.perf_counter()
                viewer.frame.value = (s + 1) % n
                viewer.draw()
                while True:
                    img = _canvas(page)
                    if (np.abs(img - before).max(-1) > 24).mean() > 0.02 or time.perf_counter() - t > 600:
                        break
                times.append(time.perf_counter() - t)
            out["switch_s"] = float(np.median(times))
            out["switch_all_s"] = [round(x, 2) for x in times]
    finally:
        stop_server(server)
    return out


@contextlib.contextmanager
def small_root(voxel_sizes: str):
    with tempfile.TemporaryDirectory(prefix="bench-viewer-") as tmp:
        root = f"{tmp}/data"
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "carlaocc", "run", "--root", root, "--voxel-size", voxel_sizes,
                        "--limit-frames", "2", "--sequences", "town00_high_seq000",
                        "--stages", "ingest,scenes,splits,voxelize,sensors"], check=True, capture_output=True)
        print(f"built {root} at {voxel_sizes} m, 2 frames: {time.perf_counter() - t0:.0f} s")
        yield root


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root")
    ap.add_argument("--voxel-sizes", default="0.2,0.05")
    ap.add_argument("--budget", type=int, default=DEFAULT_BUDGET)
    args = ap.parse_args(argv if argv is not None else sys.argv[1:] if __name__ == "__main__" else [])
    sizes = [float(x) for x in args.voxel_sizes.split(",")]
    with (contextlib.nullcontext(args.root) if args.root else small_root(args.voxel_sizes)) as root:
        print(f"{'voxel':>6} {'occupied':>10} {'drawn':>9} {'point':>6} {'prepare':>8} {'CPU':>5} {'first pic':>9} "
              f"{'switch':>7} {'shot':>6}   (s; budget {args.budget:,} drawn voxels)")
        for voxel_size in sizes:
            r = measure(root, voxel_size, args.budget)
            print(f"{voxel_size:>6g} {r['occupied']:>10,} {r['drawn']:>9,} {r['point_size']:>6g} {r['prepare_s']:>8.2f} "
                  f"{r['prepare_cpu_s']:>5.2f} "
                  f"{r['first_picture_s']:>9.2f} {r['switch_s']:>7.2f} {r['screenshot_s']:>6.2f}   "
                  f"switches {r['switch_all_s']}", flush=True)


if __name__ == "__main__":
    main()
