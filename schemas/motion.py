"""Skeleton motion clips: a joint hierarchy and its per-frame channel values, as a motion-capture
file states them.

:func:`carlaocc.catalog.bvh.read_bvh` returns a :class:`MotionClip`; the Skeletal Motion Analyzer
(:mod:`carlaocc.stages.scenes.people.gait`) takes it. No unit or axis conversion happens in the clip:
lengths are the file's units, angles degrees, axes the file's (BVH: Y up). The Y-up -> Z-up
conversion is done once, in :func:`carlaocc.stages.scenes.people.gait.kinematics.forward_kinematics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MotionClip"]


@dataclass(frozen=True)
class MotionClip:
    """A skeleton motion clip (units as in the file; angles in degrees; BVH axes, Y up).

    joint_names: one name per joint, depth-first file order (root first).
    parents:     (J,) int64, parent index of each joint, -1 for the root.
    offsets:     (J, 3) float64 joint offsets from the parent, in the parent's frame.
    channels:    per joint, the tuple of channel names in file order (e.g.
                 ``("Xposition", ..., "Zrotation", "Yrotation", "Xrotation")``).
    frame_time:  seconds per frame.
    motion:      (F, C) float64, C = total channel count, columns in joint-then-channel order.
    end_offsets: (J, 3) float64 offset of the joint's End Site (NaN when it has none).
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    motion: np.ndarray
    end_offsets: np.ndarray

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def channel_start(self) -> np.ndarray:
        """(J,) index of each joint's first column in ``motion``."""
        counts = np.array([len(c) for c in self.channels], dtype=np.int64)
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r} in the motion clip") from None
