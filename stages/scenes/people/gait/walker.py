"""Walk sources: phase-labelled walks (:class:`Walk`) made by the procedural articulated walker
(:func:`procedural_walk`, posed by :func:`articulated_pose`) or resampled from a recorded one
(:func:`resample_walk`), and joint noise (:func:`add_joint_noise`). Gait-joint positions in our
Z-up frame; metres, seconds, radians; phases in [0, 1) (see :mod:`carlaocc.stages.scenes.people.gait.cycles`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlaocc.stages.scenes.people.gait.kinematics import PELVIS, UP


@dataclass(frozen=True)
class Walk:
    """A phase-labelled walk: gait-joint positions (F, 7, 3), times (F,), phases (F,) in [0, 1)
    (NaN where unknown/standing)."""

    positions: np.ndarray
    times: np.ndarray
    phases: np.ndarray


def articulated_pose(
    phi: np.ndarray,
    stride: np.ndarray | float,
    thigh: float = 0.45,
    shin: float = 0.43,
    hip_width: float = 0.18,
) -> np.ndarray:
    """Gait joints (F, 7, 3) of the procedural articulated walker posed at phases ``phi`` (F,) with
    stride (one full cycle, m; scalar or (F,)), in the walker's heading frame (+X forward, +Y left,
    Z up) with the pelvis horizontally at the origin.

    Left hip flexion ``A cos(2 pi phi)`` with ``A = asin(min(0.95, stride / (4 leg)))``; knee flexion
    a stance bump (15 deg at phi = 0.12) plus a swing peak (60 deg at phi = 0.72), Gaussian-shaped,
    plus 3 deg; the right leg is the left one half a cycle later. The pelvis height keeps the lower
    ankle 0.08 m above the ground. A frame whose phase is NaN or whose stride is 0 stands still
    (straight legs, knees bent 3 deg).
    """
    phi = np.atleast_1d(np.asarray(phi, dtype=np.float64))
    n = len(phi)
    stride = np.broadcast_to(np.asarray(stride, dtype=np.float64), (n,))
    leg = thigh + shin
    walking = np.isfinite(phi) & (stride > 0)
    ph0 = np.where(walking, phi, 0.25)
    amp = np.where(walking, np.arcsin(np.minimum(0.95, stride / (4 * leg))), 0.0)

    def knee(ph: np.ndarray) -> np.ndarray:
        def bump(c: float, w: float) -> np.ndarray:
            d = np.mod(ph - c + 0.5, 1.0) - 0.5
            return np.exp(-((d / w) ** 2))

        return np.deg2rad(15.0) * bump(0.12, 0.07) + np.deg2rad(60.0) * bump(0.72, 0.11) + np.deg2rad(3.0)

    pos = np.zeros((n, 7, 3))
    legs = []
    for side, ph in ((1.0, ph0), (-1.0, np.mod(ph0 + 0.5, 1.0))):
        hip_a = amp * np.cos(2 * np.pi * ph)
        knee_a = np.where(walking, knee(ph), np.deg2rad(3.0))
        kn = thigh * np.stack([np.sin(hip_a), -np.cos(hip_a)], axis=1)  # (forward, up) from the hip
        sh = shin * np.stack([np.sin(hip_a - knee_a), -np.cos(hip_a - knee_a)], axis=1)
        legs.append((side, kn, kn + sh))
    height = np.maximum(-legs[0][2][:, 1], -legs[1][2][:, 1]) + 0.08
    pos[:, PELVIS, 2] = height
    for k, (side, kn, an) in enumerate(legs):
        base = 1 + 3 * k
        pos[:, base, 1] = side * 0.5 * hip_width
        pos[:, base, 2] = height
        pos[:, base + 1] = pos[:, base] + np.stack([kn[:, 0], np.zeros(n), kn[:, 1]], axis=1)
        pos[:, base + 2] = pos[:, base] + np.stack([an[:, 0], np.zeros(n), an[:, 1]], axis=1)
    return pos


def walker_stride(speed: np.ndarray | float, leg: float = 0.88) -> np.ndarray:
    """Stride (m, one full cycle) of the procedural walker at ``speed`` m/s: ``1.5 leg sqrt(speed / 1.2)``."""
    return 1.5 * leg * np.sqrt(np.maximum(np.asarray(speed, dtype=np.float64), 0.0) / 1.2)


def procedural_walk(
    speed: float,
    duration: float,
    rate: float = 20.0,
    heading: float = 0.0,
    start: tuple[float, float] = (0.0, 0.0),
    phase0: float = 0.0,
    thigh: float = 0.45,
    shin: float = 0.43,
    hip_width: float = 0.18,
    stride: float | None = None,
) -> Walk:
    """A procedural articulated stick-figure walker (pelvis, hips, knees, ankles).

    Cycle: stride (one full cycle) ``S = 1.5 * leg * sqrt(speed / 1.2)`` (or ``stride`` when given),
    frequency ``speed / S``; the pose at each phase is :func:`articulated_pose`. The pelvis moves at
    constant ``speed`` along ``heading`` (radians from +X) and its height keeps the lower ankle
    0.08 m above the ground (so it bobs twice a cycle). ``speed = 0`` gives a figure standing still
    (phases NaN).
    """
    n = max(1, int(round(duration * rate)))
    t = np.arange(n) / rate
    leg = thigh + shin
    f_dir = np.array([np.cos(heading), np.sin(heading), 0.0])
    l_dir = np.cross(UP, f_dir)
    if speed > 0:
        S = float(walker_stride(speed, leg)) if stride is None else float(stride)
        phi = np.mod(phase0 + t * speed / S, 1.0)
    else:
        S, phi = 0.0, np.full(n, np.nan)
    local = articulated_pose(phi, S, thigh, shin, hip_width)
    pos = local[..., :1] * f_dir + local[..., 1:2] * l_dir + local[..., 2:3] * UP
    pos[..., :2] += np.asarray(start, dtype=np.float64) + (speed * t)[:, None, None] * f_dir[:2]
    return Walk(pos, t, phi)


def resample_walk(
    positions: np.ndarray,
    times: np.ndarray,
    phases: np.ndarray,
    speed_factor: float = 1.0,
    rate: float = 20.0,
    t_offset: float = 0.0,
) -> Walk:
    """Time-scale a labelled walk by ``speed_factor`` (cadence and speed multiply, stride kept) and
    sample it at ``rate`` Hz starting ``t_offset`` seconds (in the scaled time) after its first
    labelled frame. Only the labelled (non-NaN phase) span is used; phases are interpolated on the
    unwrapped cycle count."""
    p = np.asarray(positions, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    ph = np.asarray(phases, dtype=np.float64)
    ok = np.flatnonzero(~np.isnan(ph))
    lo, hi = ok[0], ok[-1] + 1
    p, t, ph = p[lo:hi], (t[lo:hi] - t[lo]) / speed_factor, np.unwrap(ph[lo:hi] * 2 * np.pi) / (2 * np.pi)
    ts = np.arange(t_offset, t[-1], 1.0 / rate)
    flat = p.reshape(len(t), -1)
    q = np.stack([np.interp(ts, t, flat[:, k]) for k in range(flat.shape[1])], axis=1).reshape(len(ts), *p.shape[1:])
    return Walk(q, ts - ts[0], np.mod(np.interp(ts, t, ph), 1.0))


def add_joint_noise(walk: Walk, sigma: float, rng: np.random.Generator) -> Walk:
    """The walk with i.i.d. Gaussian noise (std ``sigma`` metres) on every joint coordinate."""
    return Walk(walk.positions + rng.normal(0.0, sigma, walk.positions.shape), walk.times, walk.phases)
