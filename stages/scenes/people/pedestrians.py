"""Pedestrians posed by gait-phase matching (the paper's Skeletal Motion Analyzer, applied).

Pure numpy on arrays and :class:`~carlaocc.schemas.meshes.AssetGeometry`; nothing here opens a file.

Two halves:

* **Matching** (:func:`match_walker_phases`): the traffic simulation gives each walker a world
  track (asset-origin positions, heading yaws) and a simulated gait phase per frame. We synthesize
  the skeleton an observer would see -- the procedural articulated walker
  (:func:`carlaocc.stages.scenes.people.gait.walker.articulated_pose`) posed at the simulated phase,
  scaled to the body height, placed on the track, with 1.5 cm Gaussian joint noise -- and match
  every frame to one of the D canonical phases of :func:`walk_cycle` with the Gaussian phase
  likelihood of :func:`gait_model` (a :class:`~carlaocc.stages.scenes.people.gait.matching.GaitModel`
  calibrated on noisy procedural walks at several speeds and strides).
* **Posing** (:func:`rig_pedestrian`, :meth:`PedestrianRig.posed`): the asset's vertices are bound
  to a skeleton fitted to the asset (rest = the asset as modelled) and deformed into the canonical
  phase's limb angles by linear-blend skinning.

Frames: asset frame (+X forward, +Y left, Z up, metres, radians). The canonical cycle is in the
walker's heading frame, which is the asset frame of a walking pedestrian.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.stages.scenes.people.gait.cycles import CanonicalCycle
from carlaocc.stages.scenes.people.gait.descriptor import frame_features, window_descriptors, window_frame_features
from carlaocc.stages.scenes.people.gait.matching import GaitModel
from carlaocc.stages.scenes.people.gait.walker import add_joint_noise, articulated_pose, procedural_walk, walker_stride

STANDING = -1  # phase index of a pedestrian standing still (rest pose)

# The procedural walker's proportions (gait.walker.procedural_walk defaults) belong to a body this tall.
WALKER_HEIGHT = 1.75  # m
THIGH, SHIN, HIP_WIDTH = 0.45, 0.43, 0.18  # m, at WALKER_HEIGHT
OBSERVATION_NOISE = 0.015  # m, std of the synthesized joint noise per coordinate
ARM_GAIN = 0.7  # arm swing = -ARM_GAIN x the same-side thigh angle (arms swing against their leg)
KNEE_BLEND = 0.06  # half-width of the thigh/shin blend zone, fraction of the leg length
HIP_BLEND = 0.08  # half-width of the body/thigh blend zone (proximity-bound meshes only)
_KNEE_FRACTION = THIGH / (THIGH + SHIN)  # knee position along hip -> ankle
NOMINAL_SPEED = 1.2  # m/s, the speed assumed for a one-frame track
MIN_PROPAGATION = 5  # centred matches needed to extrapolate the phase to a run's edge frames

# bones of the pedestrian rig
BODY, THIGH_L, SHIN_L, THIGH_R, SHIN_R, ARM_L, ARM_R = range(7)
BONE_NAMES = ("body", "thigh_l", "shin_l", "thigh_r", "shin_r", "arm_l", "arm_r")
# joints reported by PedestrianRig.joints
JOINT_NAMES = ("pelvis", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle", "l_shoulder", "l_hand",
               "r_shoulder", "r_hand")  # fmt: skip
# the bones drawn between JOINT_NAMES (indices): legs, arms, shoulders, trunk
SKELETON_BONES: tuple[tuple[int, int], ...] = ((0, 1), (1, 2), (2, 3), (0, 4), (4, 5), (5, 6), (7, 9), (7, 8), (9, 10),
                                               (0, 7), (0, 9))  # fmt: skip

_LIMB = re.compile(r"^(leg|arm)[_\- ]?(l|left|r|right)$")


# --------------------------------------------------------------------------- canonical cycle and model


@lru_cache(maxsize=8)
def walk_cycle(D: int = 32) -> CanonicalCycle:
    """Canonical walk cycle of D phases of the procedural walker at 1.2 m/s (default proportions):
    phase d is :func:`carlaocc.stages.scenes.people.gait.walker.articulated_pose` at the walker's own
    phase ``d / D`` -- the phase the training walks of :func:`gait_model` are labelled with and the
    traffic simulation's ``gait_phase`` -- in the heading frame, pelvis horizontally at the origin.
    Phase 0 is the left thigh's maximum flexion, which is also (within a phase) the left ankle's
    maximum lead. Cached."""
    stride = float(walker_stride(1.2, THIGH + SHIN))
    poses = articulated_pose(np.arange(D) / D, stride, THIGH, SHIN, HIP_WIDTH)
    features = frame_features(poses, np.array([1.0, 0.0, 0.0]))
    return CanonicalCycle(poses, features, stride / 1.2, 1.2, stride, 1)


# training walks of gait_model: cadences (cycles/s) x strides (one cycle, in leg lengths) x joint
# noise (m), i.e. speeds 0.53-3.2 m/s for an adult and cadences up to a child's fast walk; each walk
# 6 s, random heading, start phase and body size (+-10 %)
TRAIN_CADENCES = (0.6, 0.8, 1.0, 1.2, 1.4, 1.6, 1.8, 2.0)
TRAIN_STRIDES = (1.1, 1.4, 1.7, 2.0)
TRAIN_NOISES = (0.0, 0.015, 0.03)
TRAIN_SEED = 20240611


def _training_walks(rate_hz: float):
    rng = np.random.default_rng(TRAIN_SEED)
    walks = []
    for cadence in TRAIN_CADENCES:
        for rel_stride in TRAIN_STRIDES:
            for sigma in TRAIN_NOISES:
                s = rng.uniform(0.9, 1.1)
                stride = rel_stride * (THIGH + SHIN) * s
                walk = procedural_walk(
                    cadence * stride, 6.0, rate_hz, heading=rng.uniform(-np.pi, np.pi), phase0=rng.uniform(),
                    thigh=THIGH * s, shin=SHIN * s, hip_width=HIP_WIDTH * s, stride=stride,
                )  # fmt: skip
                walks.append(add_joint_noise(walk, sigma, rng))
    return walks


def gait_model(D: int = 32, W: int = 11, rate_hz: float = 20.0) -> GaitModel:
    """:class:`GaitModel` (centre anchor) fitted on procedural training walks sampled at ``rate_hz``:
    cadences :data:`TRAIN_CADENCES` x strides :data:`TRAIN_STRIDES` (leg lengths) x joint noise
    :data:`TRAIN_NOISES`, from a fixed seed. Deterministic; cached per ``(D, W, rate_hz)``."""
    return _gait_model(int(D), int(W), float(rate_hz))


@lru_cache(maxsize=8)
def _gait_model(D: int, W: int, rate_hz: float) -> GaitModel:
    return GaitModel.fit(_training_walks(rate_hz), D=D, W=W, anchor="center")


# --------------------------------------------------------------------------- matching


def synthesize_skeleton(
    times: np.ndarray, positions: np.ndarray, yaws: np.ndarray, gait_phase: np.ndarray, height: float, seed: int
) -> np.ndarray:
    """(T, 7, 3) world gait joints an observer sees of one simulated walker (see
    :func:`match_walker_phases`): the procedural walker scaled by ``height / WALKER_HEIGHT``,
    posed at the simulated phase with the stride the simulation implies (horizontal speed over the
    phase rate; the walker's own speed-stride law where that is undefined or implausible, at
    :data:`NOMINAL_SPEED` for a single frame), standing
    (rest pose) where the phase is NaN, placed at the positions/yaws, plus
    :data:`OBSERVATION_NOISE` Gaussian noise drawn from ``seed``."""
    t = np.asarray(times, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    yaw = np.asarray(yaws, dtype=np.float64).reshape(-1)
    ph = np.asarray(gait_phase, dtype=np.float64).reshape(-1)
    T = len(t)
    if not (len(pos) == len(yaw) == len(ph) == T):
        raise ValueError("times, positions, yaws and gait_phase must have the same length")
    s = float(height) / WALKER_HEIGHT
    leg = (THIGH + SHIN) * s
    walking = np.isfinite(ph)
    speed = np.full(T, NOMINAL_SPEED)  # a single frame has no measurable speed
    if T >= 2:
        speed = np.linalg.norm(np.gradient(pos[:, :2], t, axis=0), axis=1)
    stride = walker_stride(speed, leg)
    for a, b in _runs(walking):
        if b - a >= 2:
            unwrapped = np.unwrap(ph[a:b] * 2 * np.pi) / (2 * np.pi)
            rate = np.gradient(unwrapped, t[a:b])
            with np.errstate(invalid="ignore", divide="ignore"):
                implied = speed[a:b] / rate
            ok = (rate > 1e-6) & (implied > 0.8 * leg) & (implied < 2.4 * leg)
            stride[a:b] = np.where(ok, implied, stride[a:b])
    stride = np.where(walking, stride, 0.0)
    local = articulated_pose(np.where(walking, ph, np.nan), stride, THIGH * s, SHIN * s, HIP_WIDTH * s)
    c, sn = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    out = np.empty_like(local)
    out[..., 0] = c * local[..., 0] - sn * local[..., 1] + pos[:, None, 0]
    out[..., 1] = sn * local[..., 0] + c * local[..., 1] + pos[:, None, 1]
    out[..., 2] = local[..., 2] + pos[:, None, 2]
    return out + np.random.default_rng(seed).normal(0.0, OBSERVATION_NOISE, out.shape)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of the maximal runs of True in a 1-D bool array."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def match_phases(
    model: GaitModel, skeleton: np.ndarray, times: np.ndarray, walking: np.ndarray, yaws: np.ndarray
) -> list[int]:
    """Matched canonical phase index per frame of an observed skeleton track (T, 7, 3).

    Frames outside ``walking`` are :data:`STANDING`. Within a walking run of m frames:

    * a frame whose centred W-frame window lies inside the run is matched on it (the model's
      descriptor; a window whose mean pelvis speed is below ``model.standing_speed`` is STANDING);
    * a frame within W // 2 of the run's ends (sequence start/end, or where the walker
      starts/stops) is extrapolated from the matched centred windows when there are at least
      :data:`MIN_PROPAGATION` walking ones: a least-squares line through the unwrapped matched
      phases of the (up to 2W) nearest ones, evaluated at the frame's time, rounded, mod D (the same
      cadence, a quarter second further);
    * otherwise (short runs) a frame is matched on the run's W-frame window nearest to it (the
      whole run when shorter than W, n >= 3 frames), with the fit's value and slope evaluated at the
      frame's own time;
    * runs of 1 or 2 frames are matched on the per-frame features alone (the rate dimensions
      marginalised out of the diagonal Gaussian), with the heading taken from the yaw.
    """
    p = np.asarray(skeleton, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    yaws = np.asarray(yaws, dtype=np.float64)
    T = len(t)
    out = np.full(T, STANDING, dtype=np.int64)
    W, D = model.W, model.D
    h = (W - 1) // 2
    groups: dict[int, list[tuple[int, int]]] = {}  # window length -> [(frame, window start)]
    short: list[int] = []  # frames of runs shorter than 3
    edges: list[tuple[int, int, int]] = []  # (run start, run end, first centred frame) to propagate
    for a, b in _runs(walking):
        m = b - a
        if m < 3:
            short += list(range(a, b))
            continue
        n = min(W, m)
        centred = range(a + h, b - (W - 1 - h)) if m >= W else range(0)
        if len(centred) >= MIN_PROPAGATION:
            groups.setdefault(W, []).extend((i, i - h) for i in centred)
            edges.append((a, b, a + h))
            continue
        for i in range(a, b):
            groups.setdefault(n, []).append((i, int(np.clip(i - h, a, b - n))))
    for n, items in groups.items():
        frames = np.array([i for i, _ in items])
        idx = np.array([s for _, s in items])[:, None] + np.arange(n)
        desc, speed = window_descriptors(p[idx], t[idx], t[frames])
        moving = speed >= model.standing_speed
        r = (desc[moving, None, :] - model.means[None]) ** 2 / model.var
        out[frames[moving]] = np.argmin(r.sum(axis=2), axis=1)
    for a, b, c in edges:
        e = b - (W - 1 - h)  # centred frames are c .. e-1
        for lo, hi, near in ((a, c, slice(c, min(e, c + 2 * W))), (e, b, slice(max(c, e - 2 * W), e))):
            if lo == hi:
                continue
            fr = np.arange(near.start, near.stop)
            fr = fr[out[fr] != STANDING]
            if len(fr) < MIN_PROPAGATION:
                continue  # the walker is (nearly) standing there: its edges stand too
            ph = np.unwrap(out[fr] * (2 * np.pi / D)) * (D / (2 * np.pi))
            slope, icpt = np.polyfit(t[fr] - t[fr].mean(), ph, 1)
            out[lo:hi] = np.mod(np.round(icpt + slope * (t[lo:hi] - t[fr].mean())), D).astype(np.int64)
    if short:
        frames = np.array(short)
        fwd = np.stack([np.cos(yaws[frames]), np.sin(yaws[frames]), np.zeros(len(frames))], axis=1)
        w = p[frames][:, None]
        seg = np.stack([np.linalg.norm(w[:, 0, 2] - w[:, 0, 1], axis=-1) + np.linalg.norm(w[:, 0, 3] - w[:, 0, 2], axis=-1),
                        np.linalg.norm(w[:, 0, 5] - w[:, 0, 4], axis=-1) + np.linalg.norm(w[:, 0, 6] - w[:, 0, 5], axis=-1)],
                       axis=1)  # fmt: skip
        feats = window_frame_features(w, fwd, seg.mean(axis=1))[:, 0]
        r = (feats[:, None, :] - model.means[None, :, :5]) ** 2 / model.var[:5]
        out[frames] = np.argmin(r.sum(axis=2), axis=1)
    return [int(v) for v in out]


def match_walker_phases(
    times: np.ndarray,
    positions: np.ndarray,
    yaws: np.ndarray,
    gait_phase: np.ndarray,
    height: float,
    seed: int,
    D: int = 32,
) -> list[int]:
    """Canonical phase index (0..D-1, or :data:`STANDING`) per frame of one simulated walker.

    ``times`` (T,) s, ``positions`` (T, 3) world positions of the asset origin, ``yaws`` (T,)
    headings (rad), ``gait_phase`` (T,) simulated phase in [0, 1), NaN where the walker stands,
    ``height`` body height (m), ``seed`` the observation-noise seed. The observed skeleton is
    :func:`synthesize_skeleton`; frames are matched by :func:`match_phases` with
    ``gait_model(D, W=11, rate)`` at the track's median frame rate (20 Hz when T < 2): a frame whose
    simulated phase is NaN, or whose window's pelvis speed is below 0.25 m/s, is STANDING; frames
    near the start/end of a walking run are extrapolated along the cadence of the run's matched
    centred windows (short runs: the nearest window inside the run, evaluated at the frame's own
    time); runs of 1-2 frames match per-frame features. Deterministic.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    ph = np.asarray(gait_phase, dtype=np.float64).reshape(-1)
    yaw = np.asarray(yaws, dtype=np.float64).reshape(-1)
    if len(t) == 0:
        return []
    rate = 20.0 if len(t) < 2 else float(np.round(1.0 / np.median(np.diff(t)), 6))
    model = gait_model(D, 11, rate)
    skel = synthesize_skeleton(t, positions, yaw, ph, height, seed)
    return match_phases(model, skel, t, np.isfinite(ph), yaw)


# --------------------------------------------------------------------------- rig and skinning


def _ry(theta: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations about +Y by ``theta``: a bone pointing down with sagittal angle a
    (``atan2(v_x, -v_z)``, + forward) turns to sagittal angle ``a - theta``."""
    c, s = np.cos(theta), np.sin(theta)
    o, z = np.ones_like(theta), np.zeros_like(theta)
    return np.moveaxis(np.array([[c, z, s], [z, o, z], [-s, z, c]]), (0, 1), (-2, -1))


def _sagittal(v: np.ndarray) -> np.ndarray:
    """Sagittal angle of a vector (from straight down, + towards +X)."""
    v = np.asarray(v, dtype=np.float64)
    return np.arctan2(v[..., 0], -v[..., 2])


def _fit_limb(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(proximal, distal) joint of a limb mesh (a capsule-like part): the principal axis through
    the centroid, oriented downwards, its ends pulled in by the limb radius (the largest distance
    of a vertex from the axis) so they sit at the hemisphere centres of a capsule."""
    c = vertices.mean(axis=0)
    X = vertices - c
    _, vecs = np.linalg.eigh(X.T @ X)
    e = vecs[:, -1]
    if e[2] > 0:
        e = -e
    u = X @ e
    radius = float(np.linalg.norm(X - u[:, None] * e, axis=1).max())
    lo, hi = float(u.min()), float(u.max())
    if hi - lo > 4 * radius:  # long enough to pull the ends in
        lo, hi = lo + radius, hi - radius
    return c + lo * e, c + hi * e


def _point_segment_distance(P: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip((P - a) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * d), axis=1)


@dataclass(frozen=True)
class PedestrianRig:
    """An asset bound to a skeleton, with its vertices precomputed in every canonical phase.

    ``rest_joints`` (11, 3) :data:`JOINT_NAMES` of the rest asset; ``bones``/``weights`` (N, 2)
    per vertex (all parts concatenated in part order): two bone indices (:data:`BONE_NAMES`) and
    their blend weights (summing to 1); ``posed_vertices`` (D, N, 3) and ``posed_joints``
    (D, 11, 3) in every phase, asset frame, feet on z = 0. ``binding`` says how it was bound:
    ``"limb-parts"`` (named leg/arm parts) or ``"proximity"`` (per-vertex nearest bone).
    """

    geometry: AssetGeometry
    D: int
    binding: str
    rest_joints: np.ndarray
    bones: np.ndarray
    weights: np.ndarray
    posed_vertices: np.ndarray
    posed_joints: np.ndarray
    part_offsets: tuple[int, ...]
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def joints(self, phase_index: int | None) -> np.ndarray:
        """(11, 3) joints :data:`JOINT_NAMES` in a phase (STANDING/None: the rest joints)."""
        d = self._check(phase_index)
        return self.rest_joints if d == STANDING else self.posed_joints[d]

    def posed(self, phase_index: int | None) -> AssetGeometry:
        """The asset deformed into canonical phase ``phase_index`` (0..D-1), asset frame: same
        parts, names, classes, materials, faces and ``part_closed``; the lowest vertex on z = 0;
        horizontally the asset frame is kept (no re-centring). STANDING (or None) returns the
        rest geometry. Results are cached per phase (read-only arrays)."""
        d = self._check(phase_index)
        if d == STANDING:
            return self.geometry
        hit = self._cache.get(d)
        if hit is not None:
            return hit
        V = self.posed_vertices[d]
        parts = []
        for k, p in enumerate(self.geometry.parts):
            v = V[self.part_offsets[k] : self.part_offsets[k + 1]].copy()
            v.flags.writeable = False
            parts.append(MeshPart(p.name, v, p.faces, p.semantic_id, p.material, p.transparent, p.color,
                                  corner_uv=p.corner_uv, image=p.image))
        out = AssetGeometry(self.geometry.asset_id, tuple(parts), self.geometry.part_closed)
        self._cache[d] = out
        return out

    def _check(self, phase_index: int | None) -> int:
        if phase_index is None or int(phase_index) == STANDING:
            return STANDING
        d = int(phase_index)
        if not 0 <= d < self.D:
            raise ValueError(f"phase index {d} outside 0..{self.D - 1} (or STANDING)")
        return d


def _limb_name(name: str) -> tuple[str, int] | None:
    m = _LIMB.match(name.strip().lower())
    if m is None:
        return None
    return m.group(1), 0 if m.group(2) in ("l", "left") else 1


def rig_pedestrian(geom: AssetGeometry, D: int = 32) -> PedestrianRig:
    """Bind a pedestrian asset (asset frame, standing) to the canonical skeleton and pose it in
    every phase of :func:`walk_cycle` ``(D)``.

    Skeleton: fitted to the asset. With parts named ``leg_<side>`` for both sides (side ``l``,
    ``left``, ``r``, ``right``) each leg's hip and ankle are the ends of its principal axis (minus
    the limb radius), the knee at ``THIGH / (THIGH + SHIN)`` of the way; ``arm_<side>`` parts give
    shoulders and hands likewise. Otherwise (``"proximity"`` binding, e.g. a single-mesh person) the
    legs are vertical at the lateral medians of the vertices below 0.45 H, hips at 0.50 H and ankles
    at 0.04 H above the lowest vertex (H the asset height).

    Skinning (linear blend, at most two bones a vertex):
    * leg parts: thigh and shin of their side, blended linearly across the knee over
      +-:data:`KNEE_BLEND` of the leg length along the leg axis;
    * arm parts: rigidly to their arm; parts whose name contains ``bag`` (not ``backpack``), held
      in the hand, rigidly to the arm of the nearer side;
    * every other part (head, hair, torso, skirt, backpack, ...) rigidly to the body;
    * proximity binding: each vertex to the nearest bone segment (body spine or a leg bone); leg
      vertices blend thigh/shin across the knee as above and body/thigh across the hip over
      +-:data:`HIP_BLEND`.

    Posing phase d: thighs and shins turn in the sagittal plane (about +Y through hip / moved
    knee) to the canonical thigh and shin angles of phase d; arms (named arm parts) to
    ``-ARM_GAIN`` x the same-side thigh angle; the body keeps its orientation; then everything is
    shifted vertically so that the lowest vertex is on z = 0 (the pelvis bobs as in the cycle).
    """
    cyc = walk_cycle(D)
    parts = geom.parts
    if not parts:
        raise ValueError("an asset without parts cannot be rigged")
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts]).tolist()
    V = np.concatenate([p.vertices for p in parts]) if offsets[-1] else np.zeros((0, 3))
    N = len(V)
    zmin, zmax = float(V[:, 2].min()), float(V[:, 2].max())
    H = zmax - zmin
    named = [_limb_name(p.name) for p in parts]
    legs = {side: k for k, nm in enumerate(named) if nm is not None and nm[0] == "leg" for side in [nm[1]]}
    arms = {side: k for k, nm in enumerate(named) if nm is not None and nm[0] == "arm" for side in [nm[1]]}
    J = np.zeros((len(JOINT_NAMES), 3))
    bones = np.full((N, 2), BODY, dtype=np.int64)
    weights = np.zeros((N, 2))
    weights[:, 0] = 1.0

    def leg_blend(P: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
        hip, ankle = J[1 + 3 * side], J[3 + 3 * side]
        d = ankle - hip
        t = (P - hip) @ d / float(d @ d)
        return t, np.clip(0.5 + (_KNEE_FRACTION - t) / (2 * KNEE_BLEND), 0.0, 1.0)

    if len(legs) == 2:
        binding = "limb-parts"
        for side, k in legs.items():
            hip, ankle = _fit_limb(parts[k].vertices)
            J[1 + 3 * side], J[3 + 3 * side] = hip, ankle
            J[2 + 3 * side] = hip + _KNEE_FRACTION * (ankle - hip)
        for side, k in arms.items():
            J[7 + 2 * side], J[8 + 2 * side] = _fit_limb(parts[k].vertices)
        for k, p in enumerate(parts):
            sl = slice(offsets[k], offsets[k + 1])
            nm = named[k]
            if nm is not None and nm[0] == "leg":
                _, w = leg_blend(p.vertices, nm[1])
                bones[sl] = (THIGH_L + 2 * nm[1], SHIN_L + 2 * nm[1])
                weights[sl, 0], weights[sl, 1] = w, 1.0 - w
            elif nm is not None and nm[0] == "arm":
                bones[sl] = ARM_L + nm[1]
            elif "bag" in p.name.lower() and "backpack" not in p.name.lower() and arms:
                cy = p.vertices[:, 1].mean()
                side = min(arms, key=lambda s: abs(J[7 + 2 * s, 1] - cy))
                bones[sl] = ARM_L + side
    else:
        binding = "proximity"
        lower = V[V[:, 2] < zmin + 0.45 * H]
        split = float(np.median(lower[:, 1]))
        for side, sel in ((0, lower[:, 1] >= split), (1, lower[:, 1] < split)):
            x, y = float(np.median(lower[sel, 0])), float(np.median(lower[sel, 1]))
            J[1 + 3 * side] = (x, y, zmin + 0.50 * H)
            J[3 + 3 * side] = (x, y, zmin + 0.04 * H)
            J[2 + 3 * side] = J[1 + 3 * side] + _KNEE_FRACTION * (J[3 + 3 * side] - J[1 + 3 * side])
        pelvis = (J[1] + J[4]) / 2
        segs = [(pelvis, pelvis + (0.0, 0.0, 0.30 * H)), (J[1], J[2]), (J[2], J[3]), (J[4], J[5]), (J[5], J[6])]
        dist = np.stack([_point_segment_distance(V, a, b) for a, b in segs], axis=1)
        near = np.argmin(dist, axis=1)  # 0 body, 1/2 left thigh/shin, 3/4 right thigh/shin
        for side in (0, 1):
            sel = (near == 1 + 2 * side) | (near == 2 + 2 * side)
            t, w = leg_blend(V[sel], side)
            hip_zone = t < _KNEE_FRACTION - KNEE_BLEND
            wb = np.clip(0.5 + t / (2 * HIP_BLEND), 0.0, 1.0)  # thigh weight against the body
            b = np.where(hip_zone[:, None], [THIGH_L + 2 * side, BODY], [THIGH_L + 2 * side, SHIN_L + 2 * side])
            ww = np.where(hip_zone, wb, w)
            bones[sel] = b
            weights[sel, 0], weights[sel, 1] = ww, 1.0 - ww
    J[0] = (J[1] + J[4]) / 2
    for side in (0, 1):  # no arm part: shoulder/hand stand in at the hip (unused by the skin)
        if side not in arms:
            J[7 + 2 * side] = J[8 + 2 * side] = J[1 + 3 * side]

    # per-phase bone transforms (D, 7, 3, 4): v' = R v + t
    cp = cyc.poses
    thigh_a = np.stack([_sagittal(cp[:, 2] - cp[:, 1]), _sagittal(cp[:, 5] - cp[:, 4])], axis=1)  # (D, 2)
    shin_a = np.stack([_sagittal(cp[:, 3] - cp[:, 2]), _sagittal(cp[:, 6] - cp[:, 5])], axis=1)
    arm_a = -ARM_GAIN * thigh_a
    Tr = np.zeros((D, 7, 3, 4))
    Tr[:, :, :, :3] = np.eye(3)
    posedJ = np.broadcast_to(J, (D,) + J.shape).copy()
    for side in (0, 1):
        hip, knee, ankle = J[1 + 3 * side], J[2 + 3 * side], J[3 + 3 * side]
        Rt = _ry(_sagittal(knee - hip) - thigh_a[:, side])
        Rs = _ry(_sagittal(ankle - knee) - shin_a[:, side])
        knee_p = hip + (Rt @ (knee - hip))
        Tr[:, THIGH_L + 2 * side, :, :3], Tr[:, THIGH_L + 2 * side, :, 3] = Rt, hip - Rt @ hip
        Tr[:, SHIN_L + 2 * side, :, :3], Tr[:, SHIN_L + 2 * side, :, 3] = Rs, knee_p - Rs @ knee
        posedJ[:, 2 + 3 * side] = knee_p
        posedJ[:, 3 + 3 * side] = knee_p + Rs @ (ankle - knee)
        if side in arms:
            sh, hand = J[7 + 2 * side], J[8 + 2 * side]
            Ra = _ry(_sagittal(hand - sh) - arm_a[:, side])
            Tr[:, ARM_L + side, :, :3], Tr[:, ARM_L + side, :, 3] = Ra, sh - Ra @ sh
            posedJ[:, 8 + 2 * side] = sh + Ra @ (hand - sh)
    Vh = np.concatenate([V, np.ones((N, 1))], axis=1)
    PV = np.einsum("dnij,nj->dni", Tr[:, bones[:, 0]], Vh) * weights[None, :, 0, None]
    PV += np.einsum("dnij,nj->dni", Tr[:, bones[:, 1]], Vh) * weights[None, :, 1, None]
    lift = -PV[:, :, 2].min(axis=1)  # feet on the ground
    PV[:, :, 2] += lift[:, None]
    posedJ[:, :, 2] += lift[:, None]
    return PedestrianRig(geom, D, binding, J, bones, weights, PV, posedJ, tuple(offsets))

