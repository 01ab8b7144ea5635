"""One voxelize task on a default-town frame, end to end, on one core: the frame's scene assembled
from the store, composed tile by tile (filled), flow, the camera and LiDAR masks, and every array
written to Zarr -- with and without the masks, and the peak memory of the worker process; at 0.05 m also with
``fill="surface"``, so what the fill adds to a frame is measured.

The embedded default's ingest and scenes stages are built once into a temporary root; each
(voxel size, masks) case then runs in a fresh process (numba limited to one thread, JIT warmed
up on the first frame, which is not timed) over ``frames`` frames of ``town00_high_seq000``.

Usage: ``python -m benchmarks.bench_frame [frames] [out.json]``.
"""

from __future__ import annotations

import sys

from benchmarks.common import default_scenes_root, run_case, save_json

VOXEL_SIZES = (0.2, 0.1, 0.05)  # ``BENCH_FRAME_VOXEL_SIZES=0.05`` keeps only some

CASE = r"""
import json, resource, sys, time
import numba
numba.set_num_threads(1)
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.spec import Partition
from carlaocc.pipeline.tasks.voxelize import occupancy_arrays, voxelize_config, voxelize_task
from carlaocc.schemas.configs import DatasetConfig
root, voxel_size, masks, frames, fill = sys.argv[1], float(sys.argv[2]), sys.argv[3] == "1", int(sys.argv[4]), sys.argv[5]
store = Store(root)
cfg = voxelize_config(DatasetConfig()).model_copy(update={"masks": masks, "fill": fill})
grid = cfg.grid(voxel_size)
seq = "town00_high_seq000"
OccupancyStore(store).create(seq, grid, 20, cfg.chunk_edge, names=occupancy_arrays(cfg))
run = lambda t: voxelize_task(store, cfg, Partition("b", {"sequence_id": seq, "voxel_size": voxel_size, "frame_index": t}))
run(0)  # JIT and per-worker caches
times = []
for t in range(1, frames + 1):
    t0 = time.perf_counter(); run(t); times.append(time.perf_counter() - t0)
print(json.dumps({"seconds": times, "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))
"""


def main(argv: list[str] | None = None) -> dict:
    import os

    global VOXEL_SIZES
    if os.environ.get("BENCH_FRAME_VOXEL_SIZES"):
        VOXEL_SIZES = tuple(float(v) for v in os.environ["BENCH_FRAME_VOXEL_SIZES"].split(","))
    argv = [] if argv is None else argv
    frames = int(argv[0]) if argv else 3
    results = {"frames": frames, "cases": []}
    with default_scenes_root() as root:
        print(f"{'voxel':>5} {'masks':>5} {'fill':>7} {'s/frame (mean)':>14} {'min':>6} {'max':>6} {'peak RSS':>9}")
        cases = [(voxel_size, masks, "auto") for voxel_size in VOXEL_SIZES for masks in (False, True)]
        cases += [(0.05, masks, "surface") for masks in (False, True)]
        for voxel_size, masks, fill in cases:
            r = run_case(CASE, root, voxel_size, "1" if masks else "0", frames, fill)
            s = r["seconds"]
            row = {"voxel_size": voxel_size, "masks": masks, "fill": fill, "mean_s": sum(s) / len(s), "min_s": min(s),
                   "max_s": max(s), "peak_rss_gib": r["peak_rss_gib"]}
            results["cases"].append(row)
            print(f"{voxel_size:>5} {'yes' if masks else 'no':>5} {fill:>7} {row['mean_s']:>13.2f}s {min(s):>5.2f}s "
                  f"{max(s):>5.2f}s {row['peak_rss_gib']:>7.2f} GiB")
        by = {(c["voxel_size"], c["masks"], c["fill"]): c["mean_s"] for c in results["cases"]}
        for masks in (False, True):
            added = by[(0.05, masks, "auto")] / by[(0.05, masks, "surface")] - 1.0
            results[f"fill_added_{'with' if masks else 'without'}_masks"] = added
            print(f"0.05 m, {'with' if masks else 'without'} masks: the fill adds {100 * added:.1f} % to a frame")
    save_json(argv, 1, results)
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
