"""Skeletal Motion Analyzer: gait-phase matching of pedestrians (paper, appendix "Skeletal Motion
Analyzer").

Pure compute on arrays; nothing here opens a file or imports ``catalog``. A BVH clip enters as
duck-typed attributes (``parents``, ``offsets``, ``channels``, ``motion`` -- e.g.
``catalog.bvh.BvhClip``) or the same plain arrays passed to :func:`forward_kinematics`.

Frames and units
----------------
BVH is Y-up. :func:`forward_kinematics` converts **once** to our right-handed Z-up frame with the
cyclic axis permutation ``(x, y, z)_ours = (z, x, y)_bvh`` (BVH +Z, the conventional facing
direction, becomes our +X forward; BVH +Y up becomes +Z up; BVH +X becomes +Y left). Everything
downstream is metres, seconds, radians, Z up.

Gait skeleton
-------------
All gait analysis runs on seven joints in the order :data:`GAIT_JOINTS` (pelvis, then hip, knee,
ankle of the left and right legs). :data:`CMU_GAIT_JOINTS` maps them to CMU BVH names and
:func:`select_gait_joints` extracts them from a full skeleton.

Descriptor (paper eq. for delta_d = [dx^d, theta_rel^d])
-------------------------------------------------------
Per frame, in the walker's heading frame (forward f = horizontal pelvis displacement direction over
the window, up z):

* ``dx``  -- forward displacement differential: the forward offset of the left ankle from the right
  ankle, ``(p_lankle - p_rankle) . f``, divided by the leg length (hip-knee + knee-ankle, median
  over the window) so it is body-size invariant. It is +max near left heel strike, -max near right
  heel strike.
* ``theta_rel`` -- relative articulation angles: left/right hip flexion (thigh angle from the
  pelvis vertical in the sagittal plane, + forward) and left/right knee flexion (thigh angle minus
  shin angle in the sagittal plane, + bent).

The observation descriptor of a W-frame window (paper: window around the central frame) is the
value of these 5 per-frame features at the anchor frame plus their rate of change, both taken from a
least-squares quadratic fit over the window (which denoises them); the rate is expressed per
leg length walked (d/dt divided by speed / leg length) so walks at different speeds share a scale.
10 numbers in all. ``anchor="center"`` (paper) or ``"end"`` (causal: the window ends at the frame).

Phase matching
--------------
:class:`GaitModel` stores per-phase mean descriptors mu_d (d = 0..D-1) and one diagonal covariance
Sigma, both calibrated on phase-labelled training walks; ``phase(window)`` returns
``argmax_d log N(delta_hat; mu_d, Sigma)`` and its log-likelihood. A window whose mean horizontal
pelvis speed is below ``standing_speed`` is *standing*: phase ``None``.

Phase convention: phase 0 = maximum forward offset of the left ankle (left heel strike); phases
run over one full cycle (two steps) in [0, 1), phase index d <-> phase d / D.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

GAIT_JOINTS: tuple[str, ...] = ("pelvis", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
CMU_GAIT_JOINTS: dict[str, str] = {
    "pelvis": "Hips",
    "l_hip": "LeftHip",
    "l_knee": "LeftKnee",
    "l_ankle": "LeftAnkle",
    "r_hip": "RightHip",
    "r_knee": "RightKnee",
    "r_ankle": "RightAnkle",
}
FEATURE_NAMES: tuple[str, ...] = ("dx", "hip_l", "hip_r", "knee_l", "knee_r")
DESCRIPTOR_NAMES: tuple[str, ...] = FEATURE_NAMES + tuple(f"d_{n}" for n in FEATURE_NAMES)

# BVH Y-up -> our Z-up: ours = P @ bvh, i.e. (x, y, z)_ours = (z, x, y)_bvh. det(P) = +1.
BVH_TO_ZUP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
UP = np.array([0.0, 0.0, 1.0])
_PEL, _LH, _LK, _LA, _RH, _RK, _RA = range(7)


# --------------------------------------------------------------------------- forward kinematics


def _axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) right-handed rotation about the BVH axis ``axis`` by ``angle`` radians."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(angle), np.zeros_like(angle)
    if axis == "X":
        m = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == "Y":
        m = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        m = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.moveaxis(np.array(m), (0, 1), (-2, -1))


def forward_kinematics(
    parents: np.ndarray,
    offsets: np.ndarray,
    channels: Sequence[Sequence[str]],
    motion: np.ndarray,
    scale: float = 1.0,
    zup: bool = True,
) -> np.ndarray:
    """World joint positions (F, J, 3) of a BVH skeleton.

    Each joint's local transform is ``T(offset + position channels) @ R``, with R the product of its
    rotation channels in file order (``"Zrotation Yrotation Xrotation"`` -> Rz @ Ry @ Rx, degrees).
    Joints must be ordered parents-first (BVH file order is). ``scale`` multiplies lengths; with
    ``zup`` the result is converted from BVH Y-up to our Z-up frame (see module docstring).
    """
    parents = np.asarray(parents, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.float64)
    motion = np.atleast_2d(np.asarray(motion, dtype=np.float64))
    n_frames, n_joints = motion.shape[0], len(parents)
    if sum(len(c) for c in channels) != motion.shape[1]:
        raise ValueError("motion column count does not match the channels")
    pos = np.zeros((n_frames, n_joints, 3))
    rot = np.zeros((n_frames, n_joints, 3, 3))
    col = 0
    for j in range(n_joints):
        trans = np.broadcast_to(offsets[j], (n_frames, 3)).copy()
        r = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
        for ch in channels[j]:
            v = motion[:, col]
            col += 1
            axis, kind = ch[0].upper(), ch[1:]
            if kind == "position":
                trans[:, "XYZ".index(axis)] += v
            else:
                r = r @ _axis_rotation(axis, np.deg2rad(v))
        p = parents[j]
        if p < 0:
            pos[:, j] = trans
            rot[:, j] = r
        else:
            if p >= j:
                raise ValueError("joints must be ordered parents-first")
            pos[:, j] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], trans)
            rot[:, j] = rot[:, p] @ r
    pos *= scale
    if zup:
        pos = pos @ BVH_TO_ZUP.T
    return pos


def clip_positions(clip, scale: float = 1.0) -> np.ndarray:
    """Forward kinematics of a duck-typed clip (``parents, offsets, channels, motion``), Z-up."""
    return forward_kinematics(clip.parents, clip.offsets, clip.channels, clip.motion, scale=scale)


def select_gait_joints(
    joint_names: Sequence[str], positions: np.ndarray, mapping: dict[str, str] = CMU_GAIT_JOINTS
) -> np.ndarray:
    """(F, 7, 3) positions of :data:`GAIT_JOINTS` picked from a full skeleton by ``mapping``."""
    names = list(joint_names)
    idx = [names.index(mapping[g]) for g in GAIT_JOINTS]
    return np.asarray(positions)[:, idx]


# --------------------------------------------------------------------------- per-frame features


def _horizontal_unit(v: np.ndarray) -> np.ndarray:
    h = np.array(v, dtype=np.float64, copy=True)
    h[..., 2] = 0.0
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    return h / np.where(n > 1e-12, n, 1.0)


def leg_length(p: np.ndarray) -> float:
    """Median hip-knee + knee-ankle length over frames and both legs (metres)."""
    p = np.asarray(p)
    segs = [
        np.linalg.norm(p[:, _LK] - p[:, _LH], axis=-1) + np.linalg.norm(p[:, _LA] - p[:, _LK], axis=-1),
        np.linalg.norm(p[:, _RK] - p[:, _RH], axis=-1) + np.linalg.norm(p[:, _RA] - p[:, _RK], axis=-1),
    ]
    return float(np.median(np.concatenate(segs)))


def frame_features(p: np.ndarray, forward: np.ndarray, leg: float | None = None) -> np.ndarray:
    """(F, 5) per-frame features ``FEATURE_NAMES`` of gait-joint positions ``p`` (F, 7, 3).

    ``forward``: (3,) or (F, 3) horizontal unit heading. ``leg``: leg length (default: measured).
    """
    p = np.asarray(p, dtype=np.float64)
    fwd = np.broadcast_to(np.asarray(forward, dtype=np.float64), (p.shape[0], 3))
    leg = leg_length(p) if leg is None else leg
    # each frame as a window of one frame
    return window_frame_features(p[:, None], fwd, np.full(p.shape[0], leg, dtype=np.float64))[:, 0]


# --------------------------------------------------------------------------- window descriptor


class WindowDescriptor(NamedTuple):
    descriptor: np.ndarray | None  # (10,) or None when standing
    speed: float  # mean horizontal pelvis speed over the window, m/s
    forward: np.ndarray  # (3,) horizontal unit heading
    standing: bool


def window_descriptor(
    window: np.ndarray,
    times: np.ndarray,
    anchor: str = "center",
    standing_speed: float = 0.25,
) -> WindowDescriptor:
    """Observation descriptor (module docstring) of one window ``window`` (W, 7, 3), ``times`` (W,)."""
    w = np.asarray(window, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    if w.ndim != 3 or w.shape[1:] != (7, 3) or len(t) != len(w) or len(t) < 3:
        raise ValueError("window must be (W>=3, 7, 3) with W times")
    span = t[-1] - t[0]
    # heading and speed: least-squares line through the pelvis horizontal track (robust to noise)
    tc = t - t.mean()
    vel = (tc[:, None] * (w[:, _PEL] - w[:, _PEL].mean(axis=0))).sum(axis=0) / (tc**2).sum()
    vel[2] = 0.0
    speed = float(np.linalg.norm(vel))
    if speed < standing_speed or span <= 0:
        fwd = _horizontal_unit(np.cross(w[:, _LH] - w[:, _RH], UP).mean(axis=0))
        return WindowDescriptor(None, speed, fwd, True)
    fwd = vel / speed
    leg = leg_length(w)
    feats = frame_features(w, fwd, leg)
    t0 = t[-1] if anchor == "end" else (t[0] + t[-1]) / 2 if anchor == "center" else None
    if t0 is None:
        raise ValueError("anchor must be 'center' or 'end'")
    x = t - t0
    deg = 2 if len(t) >= 5 else 1
    coef = np.polynomial.polynomial.polyfit(x, feats, deg)  # (deg+1, 5): value, slope, ...
    value, slope = coef[0], coef[1]
    desc = np.concatenate([value, slope * leg / speed])
    return WindowDescriptor(desc, speed, fwd, False)


def window_descriptors(
    windows: np.ndarray, times: np.ndarray, anchor_times: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Batched :func:`window_descriptor` with the anchor at any time (vectorized over windows).

    ``windows`` (N, n, 7, 3) gait joints, ``times`` (N, n), ``anchor_times`` (N,). Returns the
    descriptors (N, 10) and the mean horizontal pelvis speeds (N,). For ``anchor_times`` at the
    window centres this equals ``window_descriptor(..., anchor="center")`` (rows with a speed of
    0 get NaN descriptors; the caller treats them as standing). Needs n >= 3.
    """
    w = np.asarray(windows, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    n = w.shape[1]
    if n < 3:
        raise ValueError("windows need at least 3 frames")
    tc = t - t.mean(axis=1, keepdims=True)
    pel = w[:, :, 0]
    vel = np.einsum("nf,nfi->ni", tc, pel - pel.mean(axis=1, keepdims=True)) / (tc**2).sum(axis=1)[:, None]
    vel[:, 2] = 0.0
    speed = np.linalg.norm(vel, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        fwd = vel / speed[:, None]
    seg = np.concatenate(
        [
            np.linalg.norm(w[:, :, 2] - w[:, :, 1], axis=-1) + np.linalg.norm(w[:, :, 3] - w[:, :, 2], axis=-1),
            np.linalg.norm(w[:, :, 5] - w[:, :, 4], axis=-1) + np.linalg.norm(w[:, :, 6] - w[:, :, 5], axis=-1),
        ],
        axis=1,
    )
    leg = np.median(seg, axis=1)
    feats = window_frame_features(w, fwd, leg)
    x = t - np.asarray(anchor_times, dtype=np.float64)[:, None]
    deg = 2 if n >= 5 else 1
    V = x[:, :, None] ** np.arange(deg + 1)  # (N, n, deg+1)
    coef = np.linalg.solve(np.einsum("nfa,nfb->nab", V, V), np.einsum("nfa,nfk->nak", V, feats))
    with np.errstate(invalid="ignore", divide="ignore"):
        desc = np.concatenate([coef[:, 0], coef[:, 1] * (leg / speed)[:, None]], axis=1)
    return desc, speed


def window_frame_features(w: np.ndarray, fwd: np.ndarray, leg: np.ndarray) -> np.ndarray:
    """(N, n, 5) gait.FEATURE_NAMES of windows (N, n, 7, 3), headings (N, 3), leg lengths (N,)."""

    def sagittal(v: np.ndarray) -> np.ndarray:  # angle from straight down, + forward
        return np.arctan2(np.einsum("nfi,ni->nf", v, fwd), -v[..., 2])

    out = np.empty(w.shape[:2] + (5,))
    out[..., 0] = np.einsum("nfi,ni->nf", w[:, :, _LA] - w[:, :, _RA], fwd) / leg[:, None]
    for k, (h, kn, a) in enumerate(((_LH, _LK, _LA), (_RH, _RK, _RA))):
        thigh = sagittal(w[:, :, kn] - w[:, :, h])
        out[..., 1 + k] = thigh
        out[..., 3 + k] = thigh - sagittal(w[:, :, a] - w[:, :, kn])
    return out


# --------------------------------------------------------------------------- cycle detection


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
    vel = np.gradient(p[:, _PEL], t, axis=0)
    vel[:, 2] = 0.0
    vel_s = _smooth(vel, n_s)
    speed = np.linalg.norm(vel_s, axis=1)
    fwd = _horizontal_unit(vel_s)
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
        pa = np.array([np.interp(a, t, g[:, _PEL, k]) for k in range(3)])
        pb = np.array([np.interp(b, t, g[:, _PEL, k]) for k in range(3)])
        f = _horizontal_unit(pb - pa)
        left = np.cross(UP, f)
        strides.append(float(np.linalg.norm((pb - pa)[:2])))
        rel = q - np.array([q[:, pelvis, 0], q[:, pelvis, 1], np.zeros(D)]).T[:, None, :]
        rot = np.stack([f, left, UP])  # rows: new axes
        poses.append(rel @ rot.T)
        feats.append(frame_features(gq, f))
    period = float(np.mean(np.diff(ev)))
    stride = float(np.mean(strides))
    return CanonicalCycle(np.mean(poses, axis=0), np.mean(feats, axis=0), period, stride / period, stride, len(strides))


# --------------------------------------------------------------------------- walk sources


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
    pos[:, _PEL, 2] = height
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


# --------------------------------------------------------------------------- phase model


class PhaseMatch(NamedTuple):
    phase: int | None  # matched phase index, None when standing
    log_likelihood: float  # log N(delta_hat; mu_d, Sigma) of the match (nan when standing)
    standing: bool
    speed: float  # m/s
    log_likelihoods: np.ndarray | None  # (D,) per phase


def _windows(walk: Walk, W: int, anchor: str):
    """Yield (window positions, window times, anchor phase) over a labelled walk."""
    for s in range(len(walk.times) - W + 1):
        a = s + W - 1 if anchor == "end" else s + (W - 1) // 2
        if W % 2 == 0 and anchor == "center":  # centre between two frames: interpolate the phase
            p0, p1 = walk.phases[a], walk.phases[a + 1]
            ph = np.mod(p0 + 0.5 * (np.mod(p1 - p0 + 0.5, 1.0) - 0.5), 1.0)
        else:
            ph = walk.phases[a]
        yield walk.positions[s : s + W], walk.times[s : s + W], ph


@dataclass
class GaitModel:
    """Per-phase mean descriptors ``means`` (D, 10) and one diagonal covariance ``var`` (10,)."""

    D: int
    W: int
    means: np.ndarray
    var: np.ndarray
    anchor: str = "center"
    standing_speed: float = 0.25

    @classmethod
    def fit(
        cls,
        training_walks: Sequence[Walk],
        D: int = 32,
        W: int = 11,
        anchor: str = "center",
        standing_speed: float = 0.25,
        var_floor: float = 1e-4,
    ) -> GaitModel:
        """Calibrate on phase-labelled walks (objects with ``positions, times, phases``): every
        W-frame window whose anchor frame has a phase (and that is not standing) contributes its
        descriptor (:func:`window_descriptors`, batched) to bin
        ``round(phase * D) mod D``; ``means`` are the bin means, ``var`` the pooled per-dimension
        variance of descriptors around their bin mean (plus ``var_floor``)."""
        descs, bins = [], []
        for walk in training_walks:
            n = len(walk.times)
            if n < W:
                continue
            starts = np.arange(n - W + 1)
            a = starts + (W - 1 if anchor == "end" else (W - 1) // 2)
            ph = np.asarray(walk.phases, dtype=np.float64)[a]
            if W % 2 == 0 and anchor == "center":  # centre between two frames: interpolate the phase
                p1 = np.asarray(walk.phases, dtype=np.float64)[a + 1]
                ph = np.mod(ph + 0.5 * (np.mod(p1 - ph + 0.5, 1.0) - 0.5), 1.0)
            idx = starts[:, None] + np.arange(W)
            tw = np.asarray(walk.times, dtype=np.float64)[idx]
            t0 = tw[:, -1] if anchor == "end" else (tw[:, 0] + tw[:, -1]) / 2 if anchor == "center" else None
            if t0 is None:
                raise ValueError("anchor must be 'center' or 'end'")
            desc, speed = window_descriptors(np.asarray(walk.positions, dtype=np.float64)[idx], tw, t0)
            keep = ~np.isnan(ph) & (speed >= standing_speed) & (tw[:, -1] > tw[:, 0])
            descs.extend(desc[keep])
            bins.extend((np.round(ph[keep] * D).astype(np.int64) % D).tolist())
        if not descs:
            raise ValueError("no walking windows in the training walks")
        X, b = np.asarray(descs), np.asarray(bins)
        counts = np.bincount(b, minlength=D)
        if (counts == 0).any():
            raise ValueError(f"phases without training windows: {np.flatnonzero(counts == 0).tolist()}")
        means = np.stack([X[b == d].mean(axis=0) for d in range(D)])
        var = ((X - means[b]) ** 2).mean(axis=0) + var_floor
        return cls(D, W, means, var, anchor, standing_speed)

    def log_likelihoods(self, descriptor: np.ndarray) -> np.ndarray:
        """(D,) Gaussian log-densities of a descriptor under every phase."""
        r = (np.asarray(descriptor)[None, :] - self.means) ** 2 / self.var[None, :]
        return -0.5 * r.sum(axis=1) - 0.5 * np.log(2 * np.pi * self.var).sum()

    def match(self, window: np.ndarray, times: np.ndarray | None = None, dt: float = 0.05) -> PhaseMatch:
        """Full match of an observed window (W, 7, 3); ``times`` default to ``dt`` spacing."""
        window = np.asarray(window, dtype=np.float64)
        if times is None:
            times = np.arange(len(window)) * dt
        wd = window_descriptor(window, times, self.anchor, self.standing_speed)
        if wd.standing:
            return PhaseMatch(None, float("nan"), True, wd.speed, None)
        ll = self.log_likelihoods(wd.descriptor)
        d = int(np.argmax(ll))
        return PhaseMatch(d, float(ll[d]), False, wd.speed, ll)

    def phase(self, window: np.ndarray, times: np.ndarray | None = None, dt: float = 0.05) -> tuple[int | None, float]:
        """``(phase_index, log_likelihood)`` of an observed window; ``(None, nan)`` when standing."""
        m = self.match(window, times, dt)
        return m.phase, m.log_likelihood


def phase_accuracy(model: GaitModel, walk: Walk, tolerance: int = 1) -> float:
    """Fraction of the labelled windows of ``walk`` whose matched phase is within ``tolerance``
    phase indices (circularly) of the true one; standing answers count as wrong."""
    hits, total = 0, 0
    for win, tw, ph in _windows(walk, model.W, model.anchor):
        if np.isnan(ph):
            continue
        total += 1
        d, _ = model.phase(win, tw)
        if d is None:
            continue
        true = int(np.round(ph * model.D)) % model.D
        err = abs((d - true + model.D // 2) % model.D - model.D // 2)
        hits += err <= tolerance
    return hits / total if total else float("nan")
