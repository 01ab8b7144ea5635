"""Gait cycles of a walk: the walking segment, the gait period and per-frame phase
(:func:`detect_gait_cycles`), and one canonical cycle resampled into D phases
(:func:`canonical_cycle`). Gait-joint positions (F, 7, 3) in our Z-up frame; metres, seconds.

Phase convention: phase 0 = maximum forward offset of the left ankle (left heel strike); phases
run over one full cycle (two steps) in [0, 1), phase index d <-> phase d / D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlaocc.stages.scenes.people.gait.descriptor import frame_features
from carlaocc.stages.scenes.people.gait.kinematics import PELVIS, UP, horizontal_unit


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    k = np.ones(n) / n
    pad = n // 2
    xp = np.pad(x, [(pad, n - 1 - pad)] + [(0, 0)] * (x.ndim - 1), mode="edge")
    if x.ndim == 1:
        return np.convolve(xp, k, mode="valid")
    return np.stack([np.convolve(xp[:, i], k, mode="valid") for i in range(x.shape[1])], axis=1)


@dataclass(frozen=True)
class GaitCycles:
    """Gait cycles found in a walk. Times in seconds; phases in [0, 1) (NaN = not walking)."""

    period: float  # seconds per full cycle (two steps)
    events: np.ndarray  # times of phase 0 (left ankle maximally ahead)
    phases: np.ndarray  # (F,)
    walking: np.ndarray  # (F,) bool, the longest walking segment
    speed: np.ndarray  # (F,) smoothed horizontal pelvis speed
    forward: np.ndarray  # (F, 3) smoothed horizontal heading
    dx: np.ndarray  # (F,) forward displacement differential (per leg length)


def detect_gait_cycles(p: np.ndarray, times: np.ndarray, min_speed: float = 0.5) -> GaitCycles:
    """Walking segment, gait period and per-frame phase of gait-joint positions ``p`` (F, 7, 3).

    The walking segment is the longest run of frames whose pelvis speed (smoothed over 0.5 s)
    exceeds ``min_speed`` and 60 % of the walk's 95th-percentile speed (so gait initiation,
    turning on the spot and stopping are left out). The period is the lag (0.4-2.5 s) maximising the normalised
    autocorrelation of the forward displacement differential ``dx`` over that segment (``dx``
    changes sign every step, so its period is the full cycle). Phase-0 events are the ``dx``
    maxima, at least 0.6 periods apart; phases interpolate linearly between events and extrapolate
    at the measured period up to one cycle beyond the first/last event, inside the segment.
    """
    p = np.asarray(p, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    dt = float(np.median(np.diff(t)))
    n_s = max(1, int(round(0.5 / dt)))
    vel = np.gradient(p[:, PELVIS], t, axis=0)
    vel[:, 2] = 0.0
    vel_s = _smooth(vel, n_s)
    speed = np.linalg.norm(vel_s, axis=1)
    fwd = horizontal_unit(vel_s)
    moving = speed > max(min_speed, 0.6 * float(np.percentile(speed, 95)))  # steady walking only
    # longest run of moving frames
    best, start = (0, 0), None
    for i, m in enumerate(np.append(moving, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    walking = np.zeros(len(t), dtype=bool)
    walking[best[0] : best[1]] = True
    dx = frame_features(p, fwd)[:, 0]
    seg = dx[walking] - dx[walking].mean()
    lags = np.arange(max(1, int(0.4 / dt)), min(int(2.5 / dt), len(seg) - max(1, int(0.3 / dt))))
    if len(lags) == 0:
        raise ValueError("walking segment too short to detect a gait period")
    ac = np.array([np.dot(seg[:-k], seg[k:]) / (len(seg) - k) for k in lags]) / (seg.var() + 1e-12)
    # first local maximum of the autocorrelation reaching 80 % of the best one (a lag of two
    # cycles correlates as well as one cycle; take the shortest)
    peaks = [i for i in range(1, len(ac) - 1) if ac[i] >= ac[i - 1] and ac[i] >= ac[i + 1]]
    good = [i for i in peaks if ac[i] >= 0.8 * ac.max()] or [int(np.argmax(ac))]
    period = float(lags[good[0]] * dt)
    # events: dx maxima >= 0.6 period apart, positive, within the walking segment
    idx = np.flatnonzero(walking)
    cand = [i for i in idx[1:-1] if dx[i] >= dx[i - 1] and dx[i] > dx[i + 1] and dx[i] > 0]
    cand.sort(key=lambda i: -dx[i])
    chosen: list[int] = []
    for i in cand:
        if all(abs(t[i] - t[c]) >= 0.6 * period for c in chosen):
            chosen.append(i)
    chosen.sort()
    ev = []
    for i in chosen:  # parabolic sub-frame refinement
        a, b, c = dx[i - 1], dx[i], dx[i + 1]
        den = a - 2 * b + c
        ev.append(t[i] + (0.5 * (a - c) / den * dt if abs(den) > 1e-12 else 0.0))
    events = np.asarray(ev)
    if len(events) >= 2:
        period = float(np.median(np.diff(events)))
    phases = np.full(len(t), np.nan)
    if len(events):
        tw = t[walking]
        ph = np.interp(tw, events, np.arange(len(events), dtype=np.float64))
        lo, hi = tw < events[0], tw > events[-1]
        ph[lo] = (tw[lo] - events[0]) / period
        ph[hi] = len(events) - 1 + (tw[hi] - events[-1]) / period
        ok = (ph >= -1.0) & (ph <= len(events))
        ph = np.where(ok, np.mod(ph, 1.0), np.nan)
        phases[walking] = ph
    return GaitCycles(period, events, phases, walking, speed, fwd, dx)


@dataclass(frozen=True)
class CanonicalCycle:
    """One walk cycle resampled into D phases (phase d <-> d / D).

    poses: (D, J, 3) joint positions in the walker's heading frame (+X forward, +Y left, Z up),
    pelvis horizontally at the origin. features: (D, 5) ``FEATURE_NAMES`` at each phase, averaged
    over cycles. period (s), speed (m/s) and stride (m, one full cycle) of the source walk.
    """

    poses: np.ndarray
    features: np.ndarray
    period: float
    speed: float
    stride: float
    n_cycles: int

    @property
    def D(self) -> int:
        return int(self.poses.shape[0])

    def pose(self, phase_index: int) -> np.ndarray:
        """Posed skeleton (J, 3) of a phase -- the stand-in for the paper's posed mesh M_d."""
        return self.poses[int(phase_index) % self.D]


def canonical_cycle(
    p: np.ndarray, times: np.ndarray, D: int = 32, cycles: GaitCycles | None = None, pelvis: int = 0,
    gait: np.ndarray | None = None,
) -> CanonicalCycle:
    """Resample every complete cycle (between consecutive phase-0 events) of ``p`` (F, J, 3) into D
    phases and average them in the heading frame. ``gait`` (F, 7, 3) gives the gait joints when
    ``p`` is a full skeleton (default: ``p`` itself); ``pelvis`` is the pelvis index in ``p``."""
    p = np.asarray(p, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    g = p if gait is None else np.asarray(gait, dtype=np.float64)
    cyc = detect_gait_cycles(g, t) if cycles is None else cycles
    ev = cyc.events
    if len(ev) < 2:
        raise ValueError("need at least one complete cycle (two phase-0 events)")
    flat = p.reshape(len(t), -1)
    gflat = g.reshape(len(t), -1)
    poses, feats, strides = [], [], []
    for a, b in zip(ev[:-1], ev[1:]):
        ts = a + (b - a) * np.arange(D) / D
        q = np.stack([np.interp(ts, t, flat[:, k]) for k in range(flat.shape[1])], axis=1).reshape(D, -1, 3)
        gq = np.stack([np.interp(ts, t, gflat[:, k]) for k in range(gflat.shape[1])], axis=1).reshape(D, 7, 3)
        pa = np.array([np.interp(a, t, g[:, PELVIS, k]) for k in range(3)])
        pb = np.array([np.interp(b, t, g[:, PELVIS, k]) for k in range(3)])
        f = horizontal_unit(pb - pa)
        left = np.cross(UP, f)
        strides.append(float(np.linalg.norm((pb - pa)[:2])))
        rel = q - np.array([q[:, pelvis, 0], q[:, pelvis, 1], np.zeros(D)]).T[:, None, :]
        rot = np.stack([f, left, UP])  # rows: new axes
        poses.append(rel @ rot.T)
        feats.append(frame_features(gq, f))
    period = float(np.mean(np.diff(ev)))
    stride = float(np.mean(strides))
    return CanonicalCycle(np.mean(poses, axis=0), np.mean(feats, axis=0), period, stride / period, stride, len(strides))
