"""Pedestrian speed, in one run: the Skeletal Motion Analyzer's phase matching of 64 simulated
walkers x 200 frames (after the one-off gait-model calibration, which is timed on its own), and
the skinned pedestrian rig: building a rig, posing each canonical phase the first time (builds the
posed parts) and again (cached). Measured on an idle 2-core machine: matching ~0.4 s, posing a
phase the first time well under 5 ms.

Usage: ``python -m benchmarks.bench_pedestrians [WALKERS [FRAMES]]`` (default 64 walkers, 200 frames).
"""

from __future__ import annotations

import sys
import time

import numpy as np

RATE = 20.0  # Hz, the simulation's frame rate
D = 32  # canonical phases


def _track(speed: float, frames: int, yaw0: float, phase0: float, gait_step: float, height: float = 1.75):
    """A walker track as the traffic simulation produces it: gently curving path at ``speed`` m/s,
    gait phase advancing by walked distance over the cycle length ``2 gait_step height``."""
    t = np.arange(frames) / RATE
    v = np.full(frames, float(speed))
    yaw = yaw0 + 0.2 * np.sin(0.3 * t)
    step = v[:-1, None] / RATE * np.stack([np.cos(yaw[:-1]), np.sin(yaw[:-1]), np.zeros(frames - 1)], axis=1)
    pos = np.vstack([[[3.0, -2.0, 0.1]], [3.0, -2.0, 0.1] + np.cumsum(step, axis=0)])
    walked = np.concatenate([[0.0], np.cumsum(v[:-1] / RATE)])
    return t, pos, yaw, np.mod(phase0 + walked / (2 * gait_step * height), 1.0)


def main(argv: list[str] | None = None) -> None:
    from carlaocc.schemas.configs import IngestConfig
    from carlaocc.stages.ingest import ingest_procedural
    from carlaocc.stages.scenes.people.pedestrians import gait_model, match_walker_phases, rig_pedestrian
    from carlaocc.stages.scenes.traffic.walkers import GAIT_STEP

    argv = sys.argv[1:] if argv is None else argv
    walkers = int(argv[0]) if argv else 64
    frames = int(argv[1]) if len(argv) > 1 else 200

    # 1. phase matching
    t0 = time.perf_counter()
    gait_model()
    print(f"gait model calibration (once per process): {time.perf_counter() - t0:.2f} s")
    tracks = [_track(0.8 + 0.8 * k / max(walkers - 1, 1), frames, yaw0=k, phase0=k / walkers, gait_step=GAIT_STEP)
              for k in range(walkers)]  # fmt: skip
    t0 = time.perf_counter()
    for k, (t, pos, yaw, ph) in enumerate(tracks):
        match_walker_phases(t, pos, yaw, ph, 1.75, k)
    dt = time.perf_counter() - t0
    print(f"phase matching: {walkers} walkers x {frames} frames in {dt:.3f} s "
          f"({walkers * frames / dt:,.0f} walker-frames/s)")  # fmt: skip

    # 2. rig and posing, per procedural pedestrian asset
    lib = ingest_procedural(IngestConfig())
    peds = [a for a in lib.assets if a.category == "Pedestrian"]
    print(f"\nskinned rigs, {D} phases ({len(peds)} procedural pedestrians)")
    print(f"{'asset':>28} {'rig ms':>8} {'posed first ms':>15} {'posed cached us':>16}")
    for asset in peds:
        geom = lib.geometry[asset.asset_id]
        t0 = time.perf_counter()
        rig = rig_pedestrian(geom, D)
        t_rig = time.perf_counter() - t0
        t0 = time.perf_counter()
        for d in range(D):
            rig.posed(d)  # first call per phase: builds the parts
        t_first = (time.perf_counter() - t0) / D
        t0 = time.perf_counter()
        for _ in range(10):
            for d in range(D):
                rig.posed(d)
        t_cached = (time.perf_counter() - t0) / (10 * D)
        name = f"{asset.subclass}/{asset.asset_id[:8]}"
        print(f"{name:>28} {t_rig * 1e3:>8.2f} {t_first * 1e3:>15.3f} {t_cached * 1e6:>16.1f}")


if __name__ == "__main__":
    main()
