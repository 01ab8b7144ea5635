"""Skeleton kinematics: world joint positions of a motion clip, the Y-up -> Z-up conversion, and
the seven gait joints every gait analysis runs on.

BVH is Y-up. :func:`forward_kinematics` converts **once** to our right-handed Z-up frame with the
cyclic axis permutation ``(x, y, z)_ours = (z, x, y)_bvh`` (BVH +Z, the conventional facing
direction, becomes our +X forward; BVH +Y up becomes +Z up; BVH +X becomes +Y left). Everything
downstream is metres, seconds, radians, Z up.

The gait joints, in the order :data:`GAIT_JOINTS` (indices :data:`PELVIS` ... :data:`R_ANKLE`):
pelvis, then hip, knee, ankle of the left and right legs. :data:`CMU_GAIT_JOINTS` maps them to
CMU BVH names and :func:`select_gait_joints` extracts them from a full skeleton.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlaocc.schemas.motion import MotionClip

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
# indices of the gait joints in GAIT_JOINTS order
PELVIS, L_HIP, L_KNEE, L_ANKLE, R_HIP, R_KNEE, R_ANKLE = range(7)

# BVH Y-up -> our Z-up: ours = P @ bvh, i.e. (x, y, z)_ours = (z, x, y)_bvh. det(P) = +1.
BVH_TO_ZUP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
UP = np.array([0.0, 0.0, 1.0])


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


def clip_positions(clip: MotionClip, scale: float = 1.0) -> np.ndarray:
    """World joint positions (F, J, 3) of a motion clip (:func:`forward_kinematics`), Z-up."""
    return forward_kinematics(clip.parents, clip.offsets, clip.channels, clip.motion, scale=scale)


def select_gait_joints(
    joint_names: Sequence[str], positions: np.ndarray, mapping: dict[str, str] = CMU_GAIT_JOINTS
) -> np.ndarray:
    """(F, 7, 3) positions of :data:`GAIT_JOINTS` picked from a full skeleton by ``mapping``."""
    names = list(joint_names)
    idx = [names.index(mapping[g]) for g in GAIT_JOINTS]
    return np.asarray(positions)[:, idx]


def horizontal_unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) with its z zeroed, scaled to unit length (zero vectors stay zero)."""
    h = np.array(v, dtype=np.float64, copy=True)
    h[..., 2] = 0.0
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    return h / np.where(n > 1e-12, n, 1.0)
