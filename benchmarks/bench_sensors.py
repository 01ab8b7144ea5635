"""Ray-cast sensors on one core: ray throughput against open3d's own ``cast_rays`` (the ceiling),
and seconds per frame of one sensors task end to end.

The embedded default's ingest and scenes stages are built once into a temporary root; the case
then runs in a fresh process with every kernel capped at one thread (open3d's casts, numba,
OpenCV inside D2NT):

* **rays/s**: the six rig cameras (6 x 1408 x 376 = 3.18 M rays) cast through a default-town
  frame's panoptic scene (everything within ``sensors.scene_range``), by open3d's
  ``RaycastingScene.cast_rays`` alone on the same triangles and rays (no labels: the ceiling),
  by our :func:`~carlaocc.stages.sensors.raycast.render_camera` for the clean maps (cast + planar depth +
  semantic/instance lookups) and for clean + raw maps (rays continued through glass);
* **s/frame**: one whole ``sensors_task`` (frame assembly from the store, BVH build, six cameras
  clean and raw, the compact mesh and the rectification, D2NT normals, the 32-beam LiDAR, every
  image written to Zarr and the LiDAR to Parquet), mean over warm frames, without and with the
  cameras' RGB (shading with one shadow ray per sunlit pixel): the RGB's cost as a ratio.

Usage: ``python -m benchmarks.bench_sensors [frames] [out.json]``.
"""

from __future__ import annotations

import sys

from benchmarks.common import default_scenes_root, run_case, save_json

CASE = r"""
import json, resource, sys, time
import numpy as np
import open3d as o3d
from carlaocc.catalog.store import Store
from carlaocc.catalog.sensors import SensorStore
from carlaocc.pipeline.engine.spec import Partition
from carlaocc.pipeline.tasks.frame import frame_inputs
from carlaocc.pipeline.tasks.sensors import sensor_arrays, sensor_region, sensors_config, sensors_task
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors import camera_poses
from carlaocc.stages.sensors.raycast import RayScene, _camera_rays, render_camera
from carlaocc.stages.threads import set_kernel_threads

set_kernel_threads(1)
root, frames = sys.argv[1], int(sys.argv[2])
store = Store(root)
cfg = sensors_config(DatasetConfig())
rig = cfg.rig
seq = "town00_high_seq000"
out = {}

# -- ray throughput on frame 0's scene -----------------------------------------------------------
inputs = frame_inputs(store, seq, 0, sensor_region(cfg))
mesh = flatten(inputs.scene)
poses = camera_poses(rig)
cams = cfg.selected_cameras(rig)
rays = np.concatenate([_camera_rays(c, np.ascontiguousarray(poses[c.name]).tobytes())[2] for c in cams])
out["triangles"], out["rays"] = int(len(mesh.faces)), int(len(rays))

def best(fn, n=3):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter(); fn(); ts.append(time.perf_counter() - t0)
    return min(ts)

def o3d_build():
    s = o3d.t.geometry.RaycastingScene(nthreads=1)
    s.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    s.cast_rays(o3d.core.Tensor(rays[:1]), nthreads=1)  # the BVH is built lazily, on the first cast
    return s
o3d_scene = o3d_build()
rays_t = o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays))
out["o3d_cast_s"] = best(lambda: o3d_scene.cast_rays(rays_t, nthreads=1))
out["bvh_build_s"] = best(o3d_build, 2)
ours = RayScene(mesh, nthreads=1)
ours.cast_rays(rays[:1], nthreads=1)
out["ours_clean_s"] = best(lambda: [render_camera(ours, c, poses[c.name], nthreads=1) for c in cams])
out["ours_clean_raw_s"] = best(lambda: [render_camera(ours, c, poses[c.name], raw=True, nthreads=1) for c in cams])

# -- whole sensors tasks ----------------------------------------------------------------------
ss = SensorStore(store)
for cam in cams:
    ss.create(seq, cam.name, cam.width, cam.height, 20, sensor_arrays(cfg))
for key, c in (("task_seconds_no_rgb", cfg.model_copy(update={"rgb": False})), ("task_seconds", cfg)):
    run = lambda t, c=c: sensors_task(store, c, Partition("b", {"sequence_id": seq, "frame_index": t}))
    run(0)  # per-worker caches (geometry, rays, JIT)
    times = []
    for t in range(1, frames + 1):
        t0 = time.perf_counter(); run(t); times.append(time.perf_counter() - t0)
    out[key] = times
out["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps(out))
"""


def main(argv: list[str] | None = None) -> dict:
    argv = [] if argv is None else argv
    frames = int(argv[0]) if argv else 3
    with default_scenes_root() as root:
        r = run_case(CASE, root, frames)
    n = r["rays"]
    print(f"scene: {r['triangles']:,} triangles; six cameras: {n:,} rays; one thread everywhere")
    print(f"  BVH build (open3d, 1 thread):               {r['bvh_build_s']:.3f} s")
    rows = [("open3d cast_rays (the ceiling)", r["o3d_cast_s"]),
            ("ours: clean maps (render_camera)", r["ours_clean_s"]),
            ("ours: clean + raw maps", r["ours_clean_raw_s"])]
    for name, s in rows:
        print(f"  {name:<42} {s:.3f} s  {n / s / 1e6:6.2f} M rays/s  {r['o3d_cast_s'] / s:5.2f}x of open3d")
    ts, t0 = r["task_seconds"], r["task_seconds_no_rgb"]
    print(f"sensors task (6 cameras clean+raw, rectification, normals, LiDAR, writes) without RGB: mean "
          f"{sum(t0) / len(t0):.2f} s per frame (min {min(t0):.2f}, max {max(t0):.2f})")
    print(f"  with RGB: mean {sum(ts) / len(ts):.2f} s per frame (min {min(ts):.2f}, max {max(ts):.2f}) over {len(ts)} "
          f"frames: x{sum(ts) / sum(t0):.2f}; peak RSS {r['peak_rss_gib']:.2f} GiB")
    save_json(argv, 1, r)
    return r


if __name__ == "__main__":
    main(sys.argv[1:])
