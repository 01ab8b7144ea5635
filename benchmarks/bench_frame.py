"""The whole cost of a frame: CPU seconds of every stage's warm task on one thread, per step,
against the code before this work in the same run (issue 39).

For each voxel size (0.2 m and 0.05 m by default) and each code base -- this checkout and,
with ``--before PYTHON``, another installation's interpreter (the "before" reference: e.g. a
worktree of an older commit with its own venv) -- a fresh process on the embedded default's
ingest and scenes (built once by this checkout) runs, on ``town00_high_seq000``:

* voxelize frames ``0..N+1`` (frame 0 warms numba and the per-worker buffers; frames ``1..N`` are
  timed; frame ``N+1`` only feeds quality's last pair),
* sensors frames ``0..N`` (0 warm, ``1..N`` timed),
* quality: a one-frame task ``[0, 1)`` to warm up, then one task ``[1, N+1)`` timed (the pairs
  ``(t, t+1)`` of its frames, as a run of frames of the stage does).

The figure is ``time.process_time()`` (CPU seconds of the process, every thread) of a task
divided by its frames, with BLAS, OpenMP and numba pinned to one thread: on a shared machine wall
time is noise, CPU time is the cost. With ``--repeat R`` each code base runs R times, alternating with the other, and each stage
keeps its cheapest run (load from other work only adds CPU time). Steps are the main functions a task calls (scene assembly,
tiles, masks, encoding...); each step's time excludes the steps it calls, and "other" is the
task's remainder, so a stage's steps add up to the stage. A step a code base does not have is
left blank. Peak RSS is the process's (all three stages).

With ``--two-workers N`` each code base also builds N frames with ``carlaocc run --workers 2``
(every stage, on a copy of the scenes root; the limited plan re-runs ingest and scenes) and the lineage's task-seconds a
frame are printed beside: the figure of a real build, with two workers sharing memory bandwidth.

The 104,000-frame extrapolation is ``frames * seconds / cores / 3600`` hours on 100 cores.

Usage::

    python -m benchmarks.bench_frame [--frames N] [--voxel-sizes 0.2,0.05] [--before PYTHON] [--repeat R] [--two-workers N] [--json out.json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys

from benchmarks.common import default_scenes_root

PAPER_FRAMES = 104_000
CORES = 100

CASE = r"""
import os
for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[k] = "1"
import functools, importlib, inspect, json, resource, shutil, sys, tempfile, time
import numba
numba.set_num_threads(1)
from carlaocc.catalog.store import Store
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sensors import SensorStore
from carlaocc.pipeline.engine.spec import Partition
from carlaocc.pipeline.tasks.voxelize import occupancy_arrays, voxelize_config, voxelize_task
from carlaocc.pipeline.tasks.sensors import sensor_arrays, sensors_config, sensors_task
from carlaocc.pipeline.tasks.quality import quality_task
from carlaocc.schemas.configs import DatasetConfig
try:
    from carlaocc.stages.threads import set_kernel_threads
    set_kernel_threads(1)
except ImportError:
    pass

src, voxel_size, frames = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
tmp = tempfile.mkdtemp(prefix="bench_frame-")
for name in ("admesh", "scenes", "splits", "catalog"):
    if os.path.exists(f"{src}/{name}"):
        shutil.copytree(f"{src}/{name}", f"{tmp}/{name}", symlinks=True)
store = Store(tmp)
seq = "town00_high_seq000"

# -- per-step clocks: wrappers that charge a call's CPU time to its step minus the wrapped steps it
#    calls (a stack of open steps); a generator's time is charged per next()
clock = time.process_time
spent, stack = {}, []

def _enter():
    stack.append(0.0)
    return clock()

def _leave(step, t0):
    dt = clock() - t0
    inner = stack.pop()
    spent[step] = spent.get(step, 0.0) + dt - inner
    if stack:
        stack[-1] += dt

def timed(fn, step):
    if inspect.isgeneratorfunction(fn):
        @functools.wraps(fn)
        def gen(*a, **k):
            it = fn(*a, **k)
            while True:
                t0 = _enter()
                try:
                    item = next(it)
                except StopIteration:
                    return
                finally:
                    _leave(step, t0)
                yield item
        return gen
    @functools.wraps(fn)
    def call(*a, **k):
        t0 = _enter()
        try:
            return fn(*a, **k)
        finally:
            _leave(step, t0)
    return call

missing = []  # steps this code base does not have (the code before a step was split out)

def patch(module, attr, step):
    obj = module
    try:
        if isinstance(module, str):
            obj = importlib.import_module(module)
        owner, name = obj, attr
        if "." in attr:
            cls, name = attr.split(".")
            owner = getattr(obj, cls)
        setattr(owner, name, timed(getattr(owner, name), step))
    except (ImportError, AttributeError):
        missing.append(f"{module}.{attr}")  # reported beside the figures, counted in "other"

STEPS = {
    "voxelize": [
        ("carlaocc.pipeline.tasks.voxelize", "frame_inputs", "scene assembly"),
        ("carlaocc.pipeline.tasks.voxelize", "voxelize_tiles", "tiles (surface, fill, buffers)"),
        ("carlaocc.stages.voxelize.visibility", "_Volume.pack_slab", "occupancy packing"),
        ("carlaocc.pipeline.tasks.voxelize", "actor_voxels", "flow"),
        ("carlaocc.pipeline.tasks.voxelize", "voxel_flow", "flow"),
        ("carlaocc.pipeline.tasks.voxelize", "lidar_visibility_bits", "LiDAR mask traversal"),
        ("carlaocc.pipeline.tasks.voxelize", "camera_visibility_bits", "camera mask traversal"),
        ("carlaocc.stages.voxelize.visibility", "_Volume.block", "mask unpacking"),
        ("carlaocc.pipeline.tasks.voxelize", "observed_columns", "observed bits (union, packing)"),
        ("carlaocc.pipeline.tasks.voxelize", "packed_block", "observed bits (union, packing)"),
        ("carlaocc.catalog.occupancy", "OccupancyStore.write_tile", "encoding and writing"),
        ("carlaocc.catalog.occupancy", "OccupancyStore.write_chunks", "encoding and writing"),
        ("carlaocc.catalog.occupancy", "OccupancyStore.clear_tile", "encoding and writing"),
        ("carlaocc.catalog.occupancy", "OccupancyStore.write_boxes", "encoding and writing"),
        ("carlaocc.catalog.occupancy", "OccupancyStore.write_points", "encoding and writing"),
    ],
    "sensors": [
        ("carlaocc.pipeline.tasks.sensors", "frame_inputs", "scene assembly"),
        ("carlaocc.stages.sensors.frame", "flatten", "scene assembly"),
        ("carlaocc.stages.sensors.frame", "RayScene", "ray scene (BVH)"),
        ("carlaocc.stages.sensors.frame", "render_camera", "clean + raw camera maps"),
        ("carlaocc.stages.sensors.frame", "rectify", "rectification"),
        ("carlaocc.stages.sensors.frame", "compact_mesh", "rectification"),
        ("carlaocc.stages.sensors.frame", "depth_normals", "D2NT normals"),
        ("carlaocc.stages.sensors.frame", "camera_ray_bundle", "camera rays"),
        ("carlaocc.stages.sensors.frame", "rig_camera_rays", "camera rays"),
        ("carlaocc.stages.sensors.frame", "render_rgb", "RGB"),
        ("carlaocc.stages.sensors.frame", "face_normals", "RGB"),
        ("carlaocc.stages.sensors.frame", "lidar_scan", "LiDAR"),
        ("carlaocc.catalog.sensors", "SensorStore.write_image", "encoding and writing"),
        ("carlaocc.catalog.sensors", "LidarStore.save", "encoding and writing"),
    ],
    "quality": [
        ("carlaocc.catalog.occupancy", "OccupancyStore.read_blocks", "decoding"),
        ("carlaocc.pipeline.tasks.quality", "continuity_and_ranges", "spatial continuity"),
        ("carlaocc.pipeline.tasks.quality", "temporal_consistency_counts", "temporal consistency"),
    ],
}
for stage_steps in STEPS.values():
    for module, attr, step in stage_steps:
        patch(module, attr, step)

def measure(run, keys):
    spent.clear()
    t0 = clock()
    for k in keys:
        run(k)
    total = clock() - t0
    steps = dict(spent)
    steps["other"] = total - sum(steps.values())
    return {"total": total, "steps": steps}

dcfg = DatasetConfig()
out = {"voxel_size": voxel_size, "frames": frames, "stages": {}, "missing_steps": missing}
vcfg = voxelize_config(dcfg)
grid = vcfg.grid(voxel_size)
OccupancyStore(store).create(seq, grid, 20, vcfg.chunk_edge, names=occupancy_arrays(vcfg))
vrun = lambda t: voxelize_task(store, vcfg, Partition("b", {"sequence_id": seq, "voxel_size": voxel_size, "frame_index": t}))
vrun(0)
out["stages"]["voxelize"] = measure(vrun, range(1, frames + 1))
vrun(frames + 1)

scfg = sensors_config(dcfg)
ss = SensorStore(store)
for cam in scfg.selected_cameras(scfg.rig):
    ss.create(seq, cam.name, cam.width, cam.height, 20, sensor_arrays(scfg))
srun = lambda t: sensors_task(store, scfg, Partition("b", {"sequence_id": seq, "frame_index": t}))
srun(0)
out["stages"]["sensors"] = measure(srun, range(1, frames + 1))

qcfg = dcfg.quality
qpart = lambda first, stop: Partition(f"{seq}/{grid.key}/{first:04d}", {
    "sequence_id": seq, "voxel_size": voxel_size, "grid": grid.model_dump(mode="json"), "first": first, "stop": stop})
quality_task(store, qcfg, qpart(0, 1))
out["stages"]["quality"] = measure(lambda r: quality_task(store, qcfg, qpart(*r)), [(1, frames + 1)])
out["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
shutil.rmtree(tmp, ignore_errors=True)
print(json.dumps(out))
"""


def _case(python: str, root: str, voxel_size: float, frames: int) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1")
    # run outside the checkout, so the interpreter imports its own installation of carlaocc
    out = subprocess.run([python, "-c", CASE, root, str(voxel_size), str(frames)], check=True,
                         capture_output=True, text=True, env=env, cwd="/")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _cheapest(a: dict | None, b: dict) -> dict:
    """Two runs of one code base merged: each stage from the run where it cost least; the
    larger peak RSS."""
    if a is None:
        return b
    out = dict(a, stages={s: min(a["stages"][s], b["stages"][s], key=lambda m: m["total"]) for s in a["stages"]})
    out["peak_rss_gib"] = max(a["peak_rss_gib"], b["peak_rss_gib"])
    return out


def _two_workers(python: str, src: str, voxel_size: float, frames: int) -> dict:
    """Task-seconds a frame of voxelize, sensors and quality on a LocalCluster of two
    single-threaded workers (``carlaocc run --workers 2``, the first ``frames`` frames of
    ``town00_high_seq000``), from the lineage's start and end times; the same run's wall time."""
    import shutil
    import tempfile
    import time

    tmp = tempfile.mkdtemp(prefix="bench_frame-workers-")
    try:
        shutil.copytree(src, f"{tmp}/data", symlinks=True)
        t0 = time.perf_counter()
        subprocess.run([python, "-m", "carlaocc", "run", "--root", f"{tmp}/data", "--voxel-size", str(voxel_size),
                        "--limit-frames", str(frames), "--sequences", "town00_high_seq000", "--workers", "2"],
                       check=True, capture_output=True, cwd="/")
        wall = time.perf_counter() - t0
        code = (
            "import json, sys\n"
            "from carlaocc.catalog.lineage import LineageLog\n"
            "from carlaocc.catalog.store import Store\n"
            "log = LineageLog(Store(sys.argv[1]))\n"
            "out = {s: sum((r.ended_at - r.started_at).total_seconds() for r in log.latest(s).values()\n"
            "              if r.status == 'completed') for s in ('voxelize', 'sensors', 'quality')}\n"
            "print(json.dumps(out))\n")
        out = subprocess.run([python, "-c", code, f"{tmp}/data"], check=True, capture_output=True, text=True, cwd="/")
        seconds = json.loads(out.stdout.strip().splitlines()[-1])
        return {"frames": frames, "wall_s": wall, "task_s_per_frame": {k: v / frames for k, v in seconds.items()}}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _per_frame(r: dict) -> dict[str, dict]:
    """stage -> {"total": s, "steps": {step: s}} per frame."""
    out = {}
    for stage, m in r["stages"].items():
        out[stage] = {"total": m["total"] / r["frames"], "steps": {k: v / r["frames"] for k, v in m["steps"].items()}}
    return out


def report(results: dict) -> None:
    """Print the per-stage, per-step table of each voxel size (after, before, ratio)."""
    for voxel_size, runs in results["voxel_sizes"].items():
        after = _per_frame(runs["after"])
        before = _per_frame(runs["before"]) if "before" in runs else None
        print(f"\n{voxel_size} m, CPU seconds a frame, one thread, warm task ({runs['after']['frames']} frames)")
        print(f"  {'stage / step':<36} {'after':>8} {'before':>8} {'before/after':>13}")
        whole_a = whole_b = 0.0
        for stage, m in after.items():
            b = before.get(stage) if before else None
            steps = dict.fromkeys([*m["steps"], *((b or {}).get("steps", {}))])
            whole_a += m["total"]
            whole_b += b["total"] if b else 0.0
            print(_row(stage, m["total"], b["total"] if b else None))
            for step in steps:
                if step == "other":
                    continue
                print(_row("  " + step, m["steps"].get(step), (b or {}).get("steps", {}).get(step)))
            print(_row("  other", m["steps"].get("other"), (b or {}).get("steps", {}).get("other")))
        print(_row("all stages", whole_a, whole_b if before else None))
        hours = PAPER_FRAMES * whole_a / CORES / 3600
        line = f"  {PAPER_FRAMES:,} frames on {CORES} cores: {hours:.2f} h"
        if before:
            line += f" (before: {PAPER_FRAMES * whole_b / CORES / 3600:.2f} h)"
        print(line)
        for label, run in runs.items():
            if isinstance(run, dict) and run.get("missing_steps"):
                print(f"  not in the {label} code (timed as other): {', '.join(run['missing_steps'])}")
        print(f"  peak RSS: {runs['after']['peak_rss_gib']:.2f} GiB"
              + (f" (before: {runs['before']['peak_rss_gib']:.2f} GiB)" if before else ""))
        workers = results.get("two_workers", {}).get(voxel_size)
        if workers:
            print(f"  two workers (carlaocc run --workers 2, {workers['after']['frames']} frames), task-seconds a frame:")
            for label, w in workers.items():
                t = w["task_s_per_frame"]
                print(f"    {label:<6} " + ", ".join(f"{k} {v:.2f}" for k, v in t.items())
                      + f"; all {sum(t.values()):.2f}; 104,000 frames on {CORES} cores: "
                      f"{PAPER_FRAMES * sum(t.values()) / CORES / 3600:.2f} h")


def _row(label: str, a: float | None, b: float | None) -> str:
    fa = f"{a:8.3f}" if a is not None else f"{'':>8}"
    fb = f"{b:8.3f}" if b is not None else f"{'':>8}"
    ratio = f"{b / a:12.2f}x" if a and b is not None else f"{'':>13}"
    return f"  {label:<36} {fa} {fb} {ratio}"


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2, help="timed frames per stage (after one warm-up frame)")
    ap.add_argument("--voxel-sizes", default="0.2,0.05", help="comma-separated voxel sizes, m")
    ap.add_argument("--before", help="python interpreter of the code before this work (its own installation)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each code base, alternating; the cheapest counts")
    ap.add_argument("--two-workers", type=int, default=0, metavar="N",
                    help="also run voxelize, sensors and quality on N frames with two LocalCluster workers")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args([] if argv is None else argv)
    sizes = [float(v) for v in args.voxel_sizes.split(",")]
    results: dict = {"frames": args.frames, "voxel_sizes": {}}
    codes = [(label, python) for label, python in (("after", sys.executable), ("before", args.before)) if python]
    with contextlib.ExitStack() as stack:
        # each code base on ingest and scenes it built itself (its tables may not read the other's)
        roots = {label: stack.enter_context(default_scenes_root(None if label == "after" else python))
                 for label, python in codes}
        for voxel_size in sizes:
            # the code bases alternate, ``--repeat`` times each; each stage keeps its cheapest run
            # (the machine's load only ever adds CPU time: cache and memory contention)
            runs: dict[str, dict] = {}
            for _ in range(args.repeat):
                for label, python in codes:
                    runs[label] = _cheapest(runs.get(label), _case(python, roots[label], voxel_size, args.frames))
            results["voxel_sizes"][voxel_size] = runs
            if args.two_workers:
                results.setdefault("two_workers", {})[voxel_size] = {
                    label: _two_workers(python, roots[label], voxel_size, args.two_workers) for label, python in codes}
    report(results)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
