"""Gait descriptors (paper eq. for delta_d = [dx^d, theta_rel^d]) of gait-joint positions
(F, 7, 3) in our Z-up frame (metres, seconds, radians).

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
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from carlaocc.stages.scenes.people.gait.kinematics import (
    L_ANKLE,
    L_HIP,
    L_KNEE,
    PELVIS,
    R_ANKLE,
    R_HIP,
    R_KNEE,
    UP,
    horizontal_unit,
)

FEATURE_NAMES: tuple[str, ...] = ("dx", "hip_l", "hip_r", "knee_l", "knee_r")
DESCRIPTOR_NAMES: tuple[str, ...] = FEATURE_NAMES + tuple(f"d_{n}" for n in FEATURE_NAMES)


def leg_length(p: np.ndarray) -> float:
    """Median hip-knee + knee-ankle length over frames and both legs (metres)."""
    p = np.asarray(p)
    segs = [
        np.linalg.norm(p[:, L_KNEE] - p[:, L_HIP], axis=-1) + np.linalg.norm(p[:, L_ANKLE] - p[:, L_KNEE], axis=-1),
        np.linalg.norm(p[:, R_KNEE] - p[:, R_HIP], axis=-1) + np.linalg.norm(p[:, R_ANKLE] - p[:, R_KNEE], axis=-1),
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
    vel = (tc[:, None] * (w[:, PELVIS] - w[:, PELVIS].mean(axis=0))).sum(axis=0) / (tc**2).sum()
    vel[2] = 0.0
    speed = float(np.linalg.norm(vel))
    if speed < standing_speed or span <= 0:
        fwd = horizontal_unit(np.cross(w[:, L_HIP] - w[:, R_HIP], UP).mean(axis=0))
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
    """(N, n, 5) :data:`FEATURE_NAMES` of windows (N, n, 7, 3), headings (N, 3), leg lengths (N,)."""

    def sagittal(v: np.ndarray) -> np.ndarray:  # angle from straight down, + forward
        return np.arctan2(np.einsum("nfi,ni->nf", v, fwd), -v[..., 2])

    out = np.empty(w.shape[:2] + (5,))
    out[..., 0] = np.einsum("nfi,ni->nf", w[:, :, L_ANKLE] - w[:, :, R_ANKLE], fwd) / leg[:, None]
    for k, (h, kn, a) in enumerate(((L_HIP, L_KNEE, L_ANKLE), (R_HIP, R_KNEE, R_ANKLE))):
        thigh = sagittal(w[:, :, kn] - w[:, :, h])
        out[..., 1 + k] = thigh
        out[..., 3 + k] = thigh - sagittal(w[:, :, a] - w[:, :, kn])
    return out
