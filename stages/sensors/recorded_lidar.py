"""A recorded LiDAR scan against our scene: each recorded point's beam cast through the frame's
scene mesh from the same pose, our range compared with the recorded one (matched beams).

Why beams and not our own sweep: a recorded scan keeps only the beams that returned (CARLA's
LiDAR also drops points at random), and its beam pattern need not be the rig's. Casting the
recorded beams themselves compares the two at exactly the same directions, so the difference of
ranges is the geometry's disagreement alone; the points are in the frame's LiDAR frame, whose
origin is the sensor, so the scene is that frame's scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.taxonomy import dynamic_ids
from carlaocc.stages.sensors.raycast import RayScene

__all__ = ["LidarAgreement", "AGREEMENT_TOLERANCE", "beam_ranges", "lidar_agreement"]

AGREEMENT_TOLERANCE = 0.1  # m: ranges within this count as agreeing


@dataclass(frozen=True)
class LidarAgreement:
    """Summary of one frame (see :class:`carlaocc.schemas.records.LidarAgreementRecord`)."""

    points: int
    static_points: int
    missed: int  # static points whose beam hits nothing of our scene
    median_m: float  # median |our range - recorded range| over static points (-1: none)
    p95_m: float  # 95th percentile (inf when more than 5 % missed; -1: none)
    within: float  # fraction of static points within `tolerance_m`
    tolerance_m: float


def beam_ranges(scene: RayScene, points: np.ndarray, nthreads: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Our range along each recorded point's beam: ``points`` (N, 3) in the scene frame, whose
    origin is the sensor (metres). Returns (N,) float32 ranges in metres (``inf`` where the beam
    hits nothing; a point at the origin has no direction and gets ``inf``) and (N,) int64 hit
    triangles (-1: none)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    r = np.linalg.norm(p, axis=1)
    ok = r > 1e-6
    # unit directions: the cast's t is then the range in metres
    d = np.zeros_like(p)
    d[ok] = p[ok] / r[ok, None]
    t, face = scene.cast(np.zeros(3), d, nthreads=nthreads)
    t = np.where(ok, t, np.inf).astype(np.float32)
    face = np.where(ok, face, -1)
    return t, face


def lidar_agreement(scene: RayScene, points: np.ndarray, recorded_semantic: np.ndarray, not_recorded: int = 255,
                    tolerance: float = AGREEMENT_TOLERANCE, nthreads: int = 0) -> tuple[np.ndarray, LidarAgreement]:
    """Our ranges along the recorded beams (:func:`beam_ranges`) and how they agree with the
    recorded ranges where the scene is static: a point counts when neither our hit nor the
    recording's tag (``recorded_semantic``, uint8; ``not_recorded`` where the scan has no tags)
    is a road user (:func:`~carlaocc.schemas.taxonomy.dynamic_ids`: its pose may differ between
    the recording and our posed model, and a moving one is swept during the scan)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tag = np.asarray(recorded_semantic).reshape(-1)
    ours, face = beam_ranges(scene, p, nthreads)
    # 1. which points see static geometry, by both labellings
    moving = np.array(sorted(dynamic_ids()), dtype=np.int64)
    our_sem, _ = scene.labels(face)
    static = ~np.isin(our_sem, moving) & ((tag == not_recorded) | ~np.isin(tag, moving))
    # 2. absolute range differences there (inf where our beam missed)
    err = np.abs(ours[static].astype(np.float64) - np.linalg.norm(p[static], axis=1))
    n = len(err)
    if n == 0:
        return ours, LidarAgreement(len(p), 0, 0, -1.0, -1.0, 0.0, tolerance)
    # 3. the summary: the median, the 95th percentile by rank (inf sorts last, so a few misses
    #    do not poison either)
    median = float(np.median(err))
    p95 = float(np.sort(err)[int(np.ceil(0.95 * n)) - 1])
    return ours, LidarAgreement(points=len(p), static_points=n, missed=int(np.isinf(err).sum()), median_m=median,
                                p95_m=p95, within=float((err <= tolerance).mean()), tolerance_m=tolerance)
