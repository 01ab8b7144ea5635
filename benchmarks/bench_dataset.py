"""Wall time and peak memory of a whole dataset build, as `make dataset` runs it.

Runs ``carlaocc run --voxel-size VOXEL_SIZE --root <fresh temp dir>`` in a subprocess (LocalCluster, one worker
per core) and samples the resident memory of the whole process tree (driver, scheduler, workers)
every 0.1 s. Usage: ``python -m benchmarks.bench_dataset [VOXEL_SIZE ...]`` (default 0.2).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil


def _tree_rss(proc: psutil.Process) -> int:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def measure(voxel_size: str, extra: list[str] | None = None) -> dict:
    """Build the default dataset at ``voxel_size`` into a fresh directory; returns seconds, peak GiB, size."""
    exe = Path(sys.executable).with_name("carlaocc")
    root = Path(tempfile.mkdtemp(prefix="carlaocc-bench-")) / "data"
    cmd = [str(exe), "run", "--voxel-size", voxel_size, "--root", str(root), *(extra or [])]
    t0 = time.perf_counter()
    proc = psutil.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, _tree_rss(proc))
        time.sleep(0.1)
    seconds = time.perf_counter() - t0
    out = proc.stdout.read().decode()
    if proc.returncode != 0:
        raise SystemExit(f"carlaocc run --voxel-size {voxel_size} failed ({proc.returncode}):\n{out}")
    size = sum(f.stat().st_size for f in root.rglob("*") if f.is_file())
    shutil.rmtree(root.parent)
    return {"voxel_size": voxel_size, "seconds": seconds, "peak_gib": peak / 2**30, "store_mib": size / 2**20,
            "summary": [ln for ln in out.splitlines() if ln.startswith(("ingest", "scenes", "voxelize", "sensors", "quality", "aggregate", "report")) and "tasks" not in ln]}


def main(argv: list[str] | None = None) -> None:
    for voxel_size in argv or ["0.2"]:
        r = measure(voxel_size)
        print(f"make dataset RES={r['voxel_size']}: {r['seconds']:.1f} s wall, peak memory {r['peak_gib']:.2f} GiB "
              f"(process tree), store {r['store_mib']:.1f} MiB")
        for line in r["summary"]:
            print("   ", line)


if __name__ == "__main__":
    main(sys.argv[1:])
