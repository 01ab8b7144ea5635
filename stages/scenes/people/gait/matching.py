"""Phase matching: :class:`GaitModel` stores per-phase mean descriptors mu_d (d = 0..D-1) and one
diagonal covariance Sigma, both calibrated on phase-labelled training walks; ``phase(window)``
returns ``argmax_d log N(delta_hat; mu_d, Sigma)`` and its log-likelihood (descriptors:
:mod:`carlaocc.stages.scenes.people.gait.descriptor`). A window whose mean horizontal pelvis speed is
below ``standing_speed`` is *standing*: phase ``None``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from carlaocc.stages.scenes.people.gait.descriptor import window_descriptor, window_descriptors
from carlaocc.stages.scenes.people.gait.walker import Walk


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
