"""The pipeline at the paper's scale, cut to fit one machine, resumable, and extrapolated.

Two builds, each stage run on its own (``carlaocc run --stages <stage>``) in a subprocess whose
process tree is sampled every 0.2 s (wall time, CPU seconds of every process, the peak resident
memory of the largest single process: a worker); a stage's cost per frame is its tasks' summed
run time from lineage (core-seconds: each worker is one single-threaded process):

* ``wide``: the paper preset (8 towns x 13 sequences) with ``--frames`` frames a sequence at
  ``--voxel-size`` (default 50 frames at 0.2 m: 5,200 frames);
* ``long``: one sequence of ``--long-frames`` frames (default 1,000) at ``--long-voxel-size`` (0.05 m).

Then ``carlaocc status`` on each root (time, and that it finds everything up to date), the store
size, and a table extrapolating every stage to the paper's 104,000 frames on 100 cores from the
measured CPU seconds per frame (``--extrapolate-frames``, ``--cores``).

Resuming: the roots are kept (``--work``, default ``benchmarks/results/scale``) and every finished
stage is recorded in ``<work>/scale.json`` at once; a run that is stopped (Ctrl-C, a reboot, kill
-9) and started again with the same arguments skips the recorded stages, and ``carlaocc run``
itself skips the partitions the interrupted stage had finished (the stage's figures then add the
attempts up, marked ``resumed``). ``--report`` prints the table of what is recorded so far.

    python -m benchmarks.bench_scale --frames 50 --voxel-size 0.2 --long-frames 1000 --long-voxel-size 0.05
    python -m benchmarks.bench_scale --report
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import psutil

STAGES = ("ingest", "scenes", "splits", "voxelize", "sensors", "quality", "aggregate", "report")
PAPER_FRAMES = 104_000
ONCE = ("ingest", "splits", "report")  # once per dataset, not per frame
SUBMITTED = re.compile(r"first (\d+) of (\d+) tasks submitted in ([\d.]+) s")
DEFAULT_WORK = Path(__file__).resolve().parent / "results" / "scale"


def _sample(proc: psutil.Popen, on_progress=None, interval: float = 0.2, every: float = 10.0) -> dict:
    """Wait for ``proc``, sampling its process tree: CPU seconds of every process (the last seen
    value of each pid: a finished process's are kept), peak RSS of the largest single process;
    ``on_progress(figures so far)`` every ``every`` seconds."""
    cpu: dict[int, float] = {}
    peak_proc = peak_tree = 0
    t0 = last = time.perf_counter()
    while proc.poll() is None:
        if on_progress is not None and time.perf_counter() - last > every:
            last = time.perf_counter()
            on_progress({"wall_s": last - t0, "cpu_s": sum(cpu.values()), "peak_worker_gib": peak_proc / 2**30,
                         "ran": 0})
        tree = 0
        for p in [proc, *proc.children(recursive=True)]:
            try:
                with p.oneshot():
                    t = p.cpu_times()
                    rss = p.memory_info().rss
            except psutil.Error:
                continue
            # the process's own time: a nanny's children_* would count its worker twice
            cpu[p.pid] = t.user + t.system
            peak_proc, tree = max(peak_proc, rss), tree + rss
        peak_tree = max(peak_tree, tree)
        time.sleep(interval)
    return {"cpu_s": sum(cpu.values()), "peak_worker_gib": peak_proc / 2**30, "peak_tree_gib": peak_tree / 2**30}


def _carlaocc() -> str:
    return str(Path(sys.executable).with_name("carlaocc"))


def _run_stage(root: Path, config: Path, voxel_size: str, stage: str, workers: int, on_progress=None) -> dict:
    cmd = [_carlaocc(), "run", "--root", str(root), "--config", str(config), "--voxel-size", voxel_size, "--stages", stage,
           "--workers", str(workers)]
    t0 = time.perf_counter()
    proc = psutil.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={**os.environ, "TERM": "dumb"})
    sampled = _sample(proc, on_progress)
    wall = time.perf_counter() - t0
    out = proc.stdout.read().decode(errors="replace")
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{out[-3000:]}")
    ran = re.search(rf"^{stage}: ran (\d+), skipped (\d+)", out, re.M)
    planned = re.search(rf"^{stage}: planned (\d+) partitions in ([\d.]+) s", out, re.M)
    return {"wall_s": wall, **sampled, "ran": int(ran.group(1)) if ran else 0,
            "skipped": int(ran.group(2)) if ran else 0,
            "plan_s": float(planned.group(2)) if planned else None, "log": out[-2000:]}


def _status(root: Path, config: Path, voxel_size: str) -> dict:
    t0 = time.perf_counter()
    out = subprocess.run([_carlaocc(), "status", "--root", str(root), "--config", str(config), "--voxel-size", voxel_size],
                         capture_output=True, text=True)
    return {"seconds": time.perf_counter() - t0, "up_to_date": out.returncode == 0 and "stale" not in out.stdout,
            "output": out.stdout[-2000:]}


def _task_seconds(root: Path, stage: str) -> float:
    """The summed run time of the latest task of every partition of ``stage`` (lineage's start
    and end times): the stage's core-seconds, whatever the attempts, restarts and idle cores."""
    from carlaocc.catalog.lineage import LineageLog
    from carlaocc.catalog.store import Store

    recs = [r for r in LineageLog(Store(str(root))).latest(stage).values() if r.status == "completed"]
    return sum((r.ended_at - r.started_at).total_seconds() for r in recs)


def _size(root: Path) -> int:
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def _config(kind: str, args) -> dict:
    """The build's dataset config: the paper preset cut to ``--frames`` (wide), or one town with
    one high-traffic sequence of ``--long-frames`` (long)."""
    import yaml

    from carlaocc.catalog.presets import preset_path

    cfg = yaml.safe_load(Path(preset_path("paper")).read_text())
    if kind == "wide":
        cfg["scenes"]["frame_count"] = args.frames
    else:
        town = dict(cfg["scenes"]["towns"][0], traffic_levels=["high"], sequences_per_level={"high": 1})
        cfg["scenes"]["towns"] = [town]
        cfg["scenes"]["frame_count"] = args.long_frames
    return cfg


def _load(path: Path) -> dict:
    data = json.loads(path.read_text()) if path.exists() else {}
    for b in data.values():  # files recorded before the voxel size was named so
        if isinstance(b, dict) and "res" in b:
            b.setdefault("voxel_size", b.pop("res"))
    return data


def _save(path: Path, data: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)  # a kill mid-write never loses what was recorded


def _frames(build: dict) -> int:
    return int(build["frames"])


def _per_frame(stage: dict, frames: int) -> float:
    """Core-seconds a frame: the tasks' summed run time (lineage), else the sampled CPU time."""
    return (stage.get("task_s") or stage["cpu_s"]) / frames


def report(results: dict, extrapolate_frames: int = PAPER_FRAMES, cores: int = 100) -> str:
    """Markdown tables: per build and stage (wall, CPU s per frame, frames per core-hour, peak
    worker memory), status and size; then the extrapolation to ``extrapolate_frames`` frames on
    ``cores`` cores from the CPU seconds per frame measured."""
    lines = []
    for kind in ("wide", "long"):
        b = results.get(kind)
        if not b:
            continue
        n = _frames(b)
        lines += [f"### {kind}: {b['description']} ({n:,} frames at {b['voxel_size']} m, {b['workers']} workers)", "",
                  "| stage | tasks | wall | task s / frame | frames / core-hour | peak worker | plan | first batch |",
                  "|---|---|---|---|---|---|---|---|"]
        for stage in STAGES:
            s = b["stages"].get(stage)
            if not s:
                continue
            per = _per_frame(s, n)
            fph = "-" if stage in ONCE else f"{3600 / per:,.0f}"
            plan = f"{s['plan_s']:.2f} s" if s.get("plan_s") is not None else "-"
            sub = SUBMITTED.search(s.get("log", ""))
            sub = f"{int(sub.group(1)):,} of {int(sub.group(2)):,} in {float(sub.group(3)):.2f} s" if sub else "-"
            lines.append(f"| {stage}{' (resumed)' if s.get('attempts', 1) > 1 else ''} | {s['ran']:,} | "
                         f"{s['wall_s']:.0f} s | {per:.2f} | {fph} | {s['peak_worker_gib']:.2f} GiB | {plan} | {sub} |")
        if "status" in b:
            lines.append(f"\n`carlaocc status`: {b['status']['seconds']:.1f} s "
                         f"({'up to date' if b['status']['up_to_date'] else 'NOT up to date'}); "
                         f"store {b['store_bytes'] / 2**30:.2f} GiB ({b['store_bytes'] / n / 2**20:.1f} MiB a frame)")
        lines.append("")
    long, wide = results.get("long"), results.get("wide")
    if long or wide:
        lines += [f"### Extrapolated: {extrapolate_frames:,} frames on {cores} cores", "",
                  "| stage | task s / frame (measured on) | hours on the cores | assumption |", "|---|---|---|---|"]
        total = 0.0
        for stage in STAGES:
            src = long if long and stage in long["stages"] else wide
            if not src or stage not in src["stages"]:
                continue
            per = _per_frame(src["stages"][stage], _frames(src))
            if stage in ONCE:
                lines.append(f"| {stage} | {per:.3f} ({'long' if src is long else 'wide'}) | - | once per dataset, "
                             f"not per frame |")
                continue
            hours = per * extrapolate_frames / cores / 3600
            total += hours
            why = {"scenes": "per town: frames cost grows with the sequences' length, linear",
                   "voxelize": f"per frame at {src['voxel_size']} m, linear (one task per frame)",
                   "sensors": "per frame, independent of the voxel size",
                   "quality": f"per frame at {src['voxel_size']} m (runs of frames_per_task frames)",
                   "aggregate": "per sequence; reads only per-frame tables"}.get(stage, "")
            lines.append(f"| {stage} | {per:.2f} ({'long' if src is long else 'wide'}) | {hours:.2f} | {why} |")
        lines.append(f"| **all** | | **{total:.2f}** | perfect scaling over {cores} cores, no I/O bound |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_scale", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--work", type=Path, default=DEFAULT_WORK, help="roots and scale.json (kept to resume)")
    p.add_argument("--frames", type=int, default=50, help="frames a sequence of the wide build")
    p.add_argument("--voxel-size", "--res", dest="voxel_size", default="0.2", help="voxel size of the wide build, m (--res is the short alias)")
    p.add_argument("--long-frames", type=int, default=1000, help="frames of the long sequence (0: skip)")
    p.add_argument("--long-voxel-size", "--long-res", dest="long_voxel_size", default="0.05", help="voxel size of the long build, m (--long-res is the short alias)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--skip-wide", action="store_true", help="only the long build")
    p.add_argument("--extrapolate-frames", type=int, default=PAPER_FRAMES)
    p.add_argument("--cores", type=int, default=100)
    p.add_argument("--report", action="store_true", help="print the recorded figures and stop")
    if argv is None and __name__ != "__main__":
        # `make bench` runs every benchmark's main(): this one takes hours, so it only reports
        path = DEFAULT_WORK / "scale.json"
        print(report(_load(path)) if path.exists() else "bench_scale: hours of work; run "
              "`python -m benchmarks.bench_scale --help` for its options")
        return
    args = p.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    path = args.work / "scale.json"
    results = _load(path)
    if args.report:
        # the tasks' run times from each root's lineage (figures recorded before they were kept)
        for kind, b in results.items():
            for stage, r in b.get("stages", {}).items():
                if r.get("complete") and (args.work / kind).exists():
                    r["task_s"] = _task_seconds(args.work / kind, stage)
        _save(path, results)
        print(report(results, args.extrapolate_frames, args.cores))
        return
    import yaml

    builds = [] if args.skip_wide else [("wide", args.voxel_size)]
    if args.long_frames:
        builds.append(("long", args.long_voxel_size))
    for kind, voxel_size in builds:
        cfg = _config(kind, args)
        towns = cfg["scenes"]["towns"]
        n_seq = sum(sum(t["sequences_per_level"].get(lv, 0) for lv in t["traffic_levels"]) for t in towns)
        frames = n_seq * cfg["scenes"]["frame_count"]
        desc = (f"{len(towns)} towns x {n_seq // len(towns)} sequences x {cfg['scenes']['frame_count']} frames"
                if kind == "wide" else f"1 sequence x {cfg['scenes']['frame_count']} frames")
        b = results.setdefault(kind, {})
        if b.get("frames") not in (None, frames) or b.get("voxel_size") not in (None, voxel_size):
            raise SystemExit(f"{path} records a {kind} build of {b.get('frames')} frames at {b.get('voxel_size')} m; "
                             f"give another --work for {frames} frames at {voxel_size} m")
        b.update({"frames": frames, "voxel_size": voxel_size, "workers": args.workers, "description": desc})
        b.setdefault("stages", {})
        root = args.work / kind
        config = args.work / f"{kind}.yaml"
        config.write_text(yaml.safe_dump(cfg, sort_keys=False))
        for stage in STAGES:
            done = b["stages"].get(stage)
            if done and done.get("complete"):
                continue
            print(f"[{kind}] {stage} ...", flush=True)

            def merged(r: dict, complete: bool, done=done) -> dict:
                if done:  # an interrupted earlier attempt: add its figures up
                    r = dict(r)
                    for k in ("wall_s", "cpu_s", "ran"):
                        r[k] += done.get(k, 0)
                    r["peak_worker_gib"] = max(r["peak_worker_gib"], done.get("peak_worker_gib", 0))
                    r["attempts"] = done.get("attempts", 1) + 1
                return {**r, "complete": complete}

            def progress(partial: dict, stage=stage, merged=merged) -> None:
                b["stages"][stage] = merged(partial, False)
                _save(path, results)  # what an interruption would otherwise lose

            r = merged(_run_stage(root, config, voxel_size, stage, args.workers, progress), True)
            r["task_s"] = _task_seconds(root, stage)
            b["stages"][stage] = r
            _save(path, results)
            print(f"[{kind}] {stage}: {r['ran']} tasks, {r['wall_s']:.0f} s wall, {_per_frame(r, frames):.2f} task s a "
                  f"frame, peak worker {r['peak_worker_gib']:.2f} GiB", flush=True)
        b["status"] = _status(root, config, voxel_size)
        b["store_bytes"] = _size(root)
        _save(path, results)
    print(report(results, args.extrapolate_frames, args.cores))


if __name__ == "__main__":
    main(sys.argv[1:])
