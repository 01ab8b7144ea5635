"""The standalone ``carlaocc voxelize`` as a whole process against open3d's, in one run.

The bench street of :mod:`benchmarks.bench_voxelize` (its ~1.07 M-triangle scene culled to the
default region) is written as one binary PLY. Then, each as a fresh child process on the same PLY
and the same grid (the mesh's bounding box snapped to the voxel lattice, what ``carlaocc voxelize``
takes when given no ``--origin``/``--shape``):

* ours: ``carlaocc voxelize street.ply --class Building --fill surface --voxel-size V --out X.npz``
  (reading the mesh, voxelizing, writing the npz: everything a user waits for);
* open3d: a python process that reads the PLY (``open3d.io.read_triangle_mesh``), runs
  ``VoxelGrid.create_from_triangle_mesh_within_bounds`` on the grid's bounds and extracts the
  voxel indices through ``get_voxels()``, saving them as an ``.npy``;
* optionally (``--before PYTHON``) the ``carlaocc voxelize`` of another installation (e.g. the
  code before this work), whose file is read with :func:`carlaocc.catalog.voxel_file.load_voxels`.

Each child's wall time, CPU time (user + system, from ``os.wait4``: that child alone) and peak
RSS (the child is started by a small runner process, not by this one, whose own RSS Linux would
count in the child's peak) are printed with the ratios; the voxel sets are compared (IoU, as bench_voxelize does:
open3d's voxels outside the grid dropped) so the speed is not bought with a wrong answer, and
the other installation's arrays must equal ours exactly.

Usage: ``python -m benchmarks.bench_standalone [--voxel-size 0.05] [--repeat 1] [--before PYTHON]
[--json out.json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

OPEN3D_CHILD = r"""
import sys, time
import numpy as np
import open3d as o3d
ply, voxel_size, out = sys.argv[1], float(sys.argv[2]), sys.argv[6]
lo = np.array([float(c) for c in sys.argv[3].split(",")])
shape = np.array([int(c) for c in sys.argv[4].split(",")])
hi = np.array([float(c) for c in sys.argv[5].split(",")])
t0 = time.perf_counter()
mesh = o3d.io.read_triangle_mesh(ply)
t1 = time.perf_counter()
vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(mesh, voxel_size, lo, hi)
t2 = time.perf_counter()
ijk = np.array([v.grid_index for v in vg.get_voxels()], dtype=np.int64).reshape(-1, 3)
t3 = time.perf_counter()
np.save(out, ijk)
print(f"open3d: read {t1 - t0:.2f} s, voxelize {t2 - t1:.2f} s, get_voxels {t3 - t2:.2f} s, "
      f"save {time.perf_counter() - t3:.2f} s", file=sys.stderr)
"""


# Starts argv[1:] and prints its wall seconds and os.wait4 rusage as JSON on the last line of
# stderr. The measured child is started from this small interpreter, not from the benchmark's own
# process: Linux carries a process's peak RSS across exec (and a vfork child shares its parent's
# memory until then), so a child of the benchmark, which holds the street scene, would report the
# benchmark's RSS as its own peak (0.49 GiB where the command itself peaks at 0.35).
RUNNER = r"""
import json, os, subprocess, sys, time
t0 = time.perf_counter()
proc = subprocess.Popen(sys.argv[1:])
_, status, ru = os.wait4(proc.pid, 0)
proc.returncode = os.waitstatus_to_exitcode(status)
print(json.dumps({"wall_s": time.perf_counter() - t0, "code": proc.returncode, "user_s": ru.ru_utime,
                  "sys_s": ru.ru_stime, "maxrss_kib": ru.ru_maxrss}), file=sys.stderr)
"""


def _run(cmd: list[str], cwd: str) -> dict:
    """Run ``cmd`` as a child of a small runner; its wall seconds, CPU seconds (user, system) and
    peak RSS (GiB) from ``os.wait4`` (this child's own rusage, not the maximum over every child)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        subprocess.run([sys.executable, "-S", "-c", RUNNER, *cmd], cwd=cwd, stdout=out, stderr=err, text=True,
                       check=False)
        out.seek(0), err.seek(0)
        stdout, stderr = out.read(), err.read()
    lines = stderr.rstrip("\n").splitlines()
    try:
        ru = json.loads(lines[-1])
    except (IndexError, ValueError):
        raise RuntimeError(f"{' '.join(cmd)}: the runner failed:\n{stderr}") from None
    stderr = "\n".join(lines[:-1])
    if ru["code"] != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {ru['code']}:\n{stdout}\n{stderr}")
    return {"wall_s": ru["wall_s"], "user_s": ru["user_s"], "sys_s": ru["sys_s"], "cpu_s": ru["user_s"] + ru["sys_s"],
            "peak_gib": ru["maxrss_kib"] / 2**20, "stdout": stdout, "stderr": stderr}


def _best(cmd: list[str], cwd: str, repeat: int) -> dict:
    runs = [_run(cmd, cwd) for _ in range(repeat)]
    return min(runs, key=lambda r: r["cpu_s"])


def write_street_ply(path: Path) -> tuple[int, int]:
    """bench_voxelize's street culled to its region, as one binary PLY; (vertices, triangles)."""
    import trimesh

    from benchmarks.bench_voxelize import REGION_MAX, REGION_MIN, merged_culled, street_scene

    V, F = merged_culled(street_scene(), np.asarray(REGION_MIN), np.asarray(REGION_MAX))
    trimesh.Trimesh(V, F, process=False).export(path)
    return len(V), len(F)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_standalone", description=__doc__.split("\n")[0])
    ap.add_argument("--voxel-size", type=float, default=0.05)
    ap.add_argument("--repeat", type=int, default=1, help="runs of each process; the one with least CPU is kept")
    ap.add_argument("--before", help="the python of another carlaocc installation to time too (e.g. the code before)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args([] if argv is None else argv)

    from carlaocc.catalog.voxel_file import load_voxels
    from carlaocc.pipeline.commands.standalone import grid_for, load_inputs

    voxel_size = args.voxel_size
    carlaocc = str(Path(sys.executable).with_name("carlaocc"))
    with tempfile.TemporaryDirectory(prefix="bench-standalone-") as tmp:
        ply = Path(tmp) / "street.ply"
        nv, nf = write_street_ply(ply)
        # the grid the command takes by default, given to open3d as bounds
        grid = grid_for(load_inputs([str(ply)], ["Building"], None, "surface"), voxel_size)
        shape = grid.shape
        print(f"bench street: {nf:,} triangles, {nv:,} vertices, {ply.stat().st_size / 2**20:.1f} MiB PLY; "
              f"grid {shape[0]}x{shape[1]}x{shape[2]} ({np.prod(shape) / 1e6:.0f} M voxels) at {voxel_size} m")
        results: dict = {"voxel_size": voxel_size, "triangles": nf, "grid_shape": list(shape)}

        ours_cmd = [carlaocc, "voxelize", str(ply), "--class", "Building", "--fill", "surface", "--voxel-size",
                    str(voxel_size), "--out", f"{tmp}/ours.npz"]
        # a first run loads numba's compiled kernels from disk into the page cache (and compiles
        # them into the cache if they are not there): a user's second run, not their first install
        _run(ours_cmd, tmp)
        ours = _best(ours_cmd, tmp, args.repeat)
        o3d_cmd = [sys.executable, "-c", OPEN3D_CHILD, str(ply), str(voxel_size), ",".join(map(repr, grid.origin)),
                   ",".join(map(str, shape)), ",".join(map(repr, grid.effective_max)), f"{tmp}/open3d.npy"]
        theirs = _best(o3d_cmd, tmp, args.repeat)
        rows = [("carlaocc voxelize", ours), ("open3d", theirs)]
        before = None
        if args.before:
            before_cmd = [args.before, "-m", "carlaocc", *ours_cmd[1:-1], f"{tmp}/before.npz"]
            _run(before_cmd, tmp)
            before = _best(before_cmd, tmp, args.repeat)
            rows.append(("carlaocc voxelize (--before)", before))

        print(f"\nwhole processes, best of {args.repeat} by CPU (user + system of the child, os.wait4):")
        print(f"  {'process':<30} {'wall s':>7} {'CPU s':>7} {'user':>6} {'sys':>6} {'peak GiB':>9} {'open3d/this CPU':>16}")
        for name, r in rows:
            print(f"  {name:<30} {r['wall_s']:>7.2f} {r['cpu_s']:>7.2f} {r['user_s']:>6.2f} {r['sys_s']:>6.2f} "
                  f"{r['peak_gib']:>9.2f} {theirs['cpu_s'] / r['cpu_s']:>15.1f}x")
        print(f"  ours said: {ours['stdout'].strip()}")
        print(f"  {theirs['stderr'].strip().splitlines()[-1]}")
        for name, r in rows:
            results[name] = {k: v for k, v in r.items() if k not in ("stdout", "stderr")}
        results["speedup_cpu"] = theirs["cpu_s"] / ours["cpu_s"]
        results["speedup_wall"] = theirs["wall_s"] / ours["wall_s"]
        print(f"  open3d / ours: {results['speedup_cpu']:.1f}x CPU, {results['speedup_wall']:.1f}x wall; "
              f"npz {Path(tmp, 'ours.npz').stat().st_size / 2**20:.1f} MiB")

        # the same voxels? (open3d's voxels outside the grid dropped, as bench_voxelize does)
        mine = load_voxels(f"{tmp}/ours.npz")
        ours_lin = mine.index
        ijk = np.load(f"{tmp}/open3d.npy")
        inb = np.all((ijk >= 0) & (ijk < np.asarray(shape)), axis=1)
        their_lin = np.unique(np.ravel_multi_index(tuple(ijk[inb].T), shape))
        inter = len(np.intersect1d(ours_lin, their_lin, assume_unique=True))
        union = len(ours_lin) + len(their_lin) - inter
        results.update(voxels=len(ours_lin), open3d_voxels=len(their_lin), iou=inter / union,
                       only_ours=len(ours_lin) - inter, only_open3d=len(their_lin) - inter)
        print(f"  voxels: ours {len(ours_lin):,}, open3d {len(their_lin):,} in the grid; IoU {inter / union:.6f} "
              f"(only ours {len(ours_lin) - inter:,}, only open3d {len(their_lin) - inter:,}; see bench_voxelize "
              f"on lattice ties)")
        if before is not None:
            old = load_voxels(f"{tmp}/before.npz")
            same = (np.array_equal(old.index, mine.index) and np.array_equal(old.semantic, mine.semantic)
                    and np.array_equal(old.instance, mine.instance) and old.grid == mine.grid)
            results["before_identical"] = same
            print(f"  --before's arrays identical to ours: {same}")
            if not same:
                raise SystemExit("the other installation's voxels differ from ours")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
