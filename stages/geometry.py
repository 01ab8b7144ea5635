"""Geometry helpers shared by the stages: rigid transforms, mesh measures and checks.

Small pure numpy functions in the trimesh style over ``(N, 3)`` float64 vertices and ``(M, 3)``
int64 faces (the mesh types themselves, :class:`~carlaocc.schemas.meshes.MeshPart` and friends,
live in ``carlaocc.schemas.meshes``). Units are metres; poses are 4x4 float64 homogeneous matrices mapping
a source frame into a target frame (``p_target = T @ p_source``).
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

DEGENERATE_REL = 1e-12
"""A face is degenerate when twice its area is below this times the squared bbox diagonal (the
ingest stage's rule, :mod:`carlaocc.stages.ingest.repair`; the standalone voxelizer's too)."""


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 homogeneous transform to (N, 3) points; returns (N, 3) float64."""
    # rotate-scale by the upper 3x3, then translate
    pts = np.asarray(points, dtype=np.float64)
    return pts @ np.asarray(T, dtype=np.float64)[:3, :3].T + np.asarray(T, dtype=np.float64)[:3, 3]


def rotation_matrix(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """3x3 rotation of a body frame (x forward, y left, z up) with the given Tait-Bryan angles, rad.

    The convention of ROS REP 103 and of the records: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, i.e.
    roll about the body's x axis, then pitch about y, then yaw about the world's z, all
    right-handed: positive pitch turns the nose **down**, positive roll lowers the **right** side.
    (CARLA's left-handed ``Rotation`` has the opposite signs of pitch and yaw.)"""
    cy, sy = np.cos(yaw), np.sin(yaw)
    if pitch == 0.0 and roll == 0.0:
        # yaw only: the exact planar matrix (no products with cos 0 = 1 that could differ in the last bit)
        return np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def pose_matrix(x: float, y: float, z: float, yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """4x4 pose of a frame at (x, y, z) m turned by ``yaw``, ``pitch`` and ``roll`` rad
    (:func:`rotation_matrix`: ``Rz(yaw) Ry(pitch) Rx(roll)``, right-handed; yaw alone turns about +Z)."""
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(yaw, pitch, roll)
    T[:3, 3] = (x, y, z)
    return T


def yaw_pitch_roll(R: np.ndarray) -> tuple[float, float, float]:
    """The angles (rad) of :func:`rotation_matrix` that give the 3x3 rotation ``R``: yaw in
    (-pi, pi], pitch in [-pi/2, pi/2], roll in (-pi, pi]. At pitch +-pi/2 (gimbal lock) roll is 0."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    # pitch from the forward axis' fall, yaw from its heading, roll from the lateral axis' rise
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(R[2, 0]) > 1.0 - 1e-12:
        return float(np.arctan2(-R[0, 1], R[1, 1])), pitch, 0.0
    return float(np.arctan2(R[1, 0], R[0, 0])), pitch, float(np.arctan2(R[2, 1], R[2, 2]))


def tilt_to_normal(yaw, up) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll (rad) that stand a body heading ``yaw`` (rad, (...,)) on a surface whose
    upward unit normal is ``up`` ((..., 3), world frame, z up): the body's z axis becomes ``up``
    and its x axis stays in the vertical plane of the heading (so it lies in the surface).

    With ``R = Rz(yaw) Ry(pitch) Rx(roll)`` the body's up axis is ``Rz(yaw) (cos(roll) sin(pitch),
    -sin(roll), cos(roll) cos(pitch))``; turning ``up`` back by ``-yaw`` reads both angles off it.
    A level surface (0, 0, 1) gives exactly 0 and 0."""
    yaw = np.asarray(yaw, dtype=np.float64)
    n = np.asarray(up, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    # 1. the normal in the heading's frame (x along the heading, y to its left)
    c, s = np.cos(yaw), np.sin(yaw)
    nx = c * n[..., 0] + s * n[..., 1]
    ny = -s * n[..., 0] + c * n[..., 1]
    # 2. pitch tips it forward/back, roll sideways (+ 0.0: a level surface gives +0, never -0)
    pitch = np.arctan2(nx, n[..., 2]) + 0.0
    roll = np.arctan2(-ny, np.hypot(nx, n[..., 2])) + 0.0
    return pitch, roll


def angular_velocity(yaw, pitch, roll, yaw_rate, pitch_rate, roll_rate) -> np.ndarray:
    """World-frame angular velocity (..., 3) rad/s of a body with :func:`rotation_matrix` angles
    (rad) changing at the given rates (rad/s): ``yaw_rate ez + pitch_rate Rz(yaw) ey + roll_rate
    Rz(yaw) Ry(pitch) ex``. Yaw alone gives exactly (0, 0, yaw_rate)."""
    yaw, pitch = np.asarray(yaw, dtype=np.float64), np.asarray(pitch, dtype=np.float64)
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    wx = -sy * pitch_rate + cy * cp * roll_rate
    wy = cy * pitch_rate + sy * cp * roll_rate
    wz = yaw_rate - sp * roll_rate
    # + 0.0: no -0 components when only the yaw turns
    return np.stack(np.broadcast_arrays(wx + 0.0, wy + 0.0, wz + 0.0), axis=-1)


def box_center(pose: np.ndarray, height: float) -> list[float]:
    """World centre (3 floats, m) of an actor's 3D box of ``height`` m whose bottom face is centred
    on the origin of its 4x4 ``pose`` (asset-to-world): half the height up the body's z axis."""
    T = np.asarray(pose, dtype=np.float64)
    return [float(v) for v in T[:3, 3] + T[:3, 2] * (height / 2)]


def quaternion_wxyz(R: np.ndarray) -> list[float]:
    """The unit quaternion ``[w, x, y, z]`` of a 3x3 rotation matrix (w >= 0; the nuScenes and
    pyquaternion order), by Shepperd's method: the largest of the four squared components is
    taken from the trace or a diagonal element, the others from off-diagonal sums (stable for
    every rotation, 180 degree turns included)."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    # 4 * the squares of w, x, y, z
    cand = np.array([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22])
    k = int(np.argmax(cand))
    s = 2.0 * np.sqrt(cand[k])  # 4 * the largest component
    if k == 0:
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.asarray(q) / np.linalg.norm(q)
    return [float(v) for v in (q if q[0] >= 0 else -q)]


def rotation_from_quaternion(q) -> np.ndarray:
    """3x3 rotation matrix of a quaternion ``[w, x, y, z]`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (rotation transposed, translation rotated back)."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def pose_to_list(T: np.ndarray) -> list[float]:
    """Flatten a 4x4 pose row-major into 16 Python floats (the records' pose layout)."""
    return [float(v) for v in np.asarray(T, dtype=np.float64).reshape(16)]


def pose_from_list(values) -> np.ndarray:
    """Inverse of :func:`pose_to_list`."""
    return np.asarray(values, dtype=np.float64).reshape(4, 4)


def is_watertight(faces: np.ndarray) -> bool:
    """True when every undirected edge is shared by exactly two faces with opposite directions
    (a closed, consistently wound 2-manifold surface)."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return False
    # directed edges of every face, encoded as one int64 key each
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    n = int(f.max()) + 1
    keys = np.sort(a * n + b)
    # each directed edge must occur once ...
    if keys.size > 1 and np.any(keys[1:] == keys[:-1]):
        return False
    # ... and its reverse once
    rev = b * n + a
    pos = np.minimum(np.searchsorted(keys, rev), keys.size - 1)
    return bool(np.all(keys[pos] == rev))


def concatenate(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (vertices, faces) pairs into one mesh, offsetting face indices."""
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(np.asarray(v, dtype=np.float64))
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def surface_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total triangle area (m^2 for vertices in metres)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 0.0
    # half the norm of each edge cross product
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return float(0.5 * np.linalg.norm(cross, axis=1).sum())


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed mesh by the divergence theorem (m^3; positive when the faces
    wind counter-clockwise seen from outside)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 0.0
    # sum of signed tetrahedra (origin, a, b, c)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def geometry_hash(parts: list[tuple[np.ndarray, np.ndarray]], decimals: int = 5) -> str:
    """Content hash of standardized geometry: every part's vertices rounded to ``decimals``
    (10 micrometres by default, so float32 round trips agree) and faces, in part order."""
    h = hashlib.sha256()
    for v, f in parts:
        # rounding, then +0.0 so that -0.0 and 0.0 hash alike
        h.update(np.ascontiguousarray(np.round(np.asarray(v, np.float64), decimals) + 0.0).tobytes())
        h.update(np.ascontiguousarray(np.asarray(f, np.int64)).tobytes())
        h.update(b"|")
    return h.hexdigest()[:24]


BOX_KEYS = ("boxes", "box_pose", "box_velocity", "box_instance", "box_semantic")
"""The keys :func:`boxes_in_frame` returns."""


def boxes_in_frame(rows: list, world_to_frame: np.ndarray) -> dict[str, np.ndarray]:
    """Actor boxes (world-frame rows of the actors table: instance id, semantic id, centre (3,) m,
    size (l, w, h) m, yaw, pitch, roll rad, velocity (3,) m/s) in another frame, sorted by
    instance id: ``boxes`` (M, 7) float32 ``x, y, z, l, w, h, yaw`` (yaw about the frame's z from
    its x axis), ``box_pose`` (M, 4, 4) box-to-frame, ``box_velocity`` (M, 3) float32 in the
    frame's axes, ``box_instance`` (M,) uint32, ``box_semantic`` (M,) uint8."""
    R_wl, t_wl = world_to_frame[:3, :3], world_to_frame[:3, 3]
    m = len(rows)
    boxes = np.zeros((m, 7), np.float32)
    pose = np.tile(np.eye(4), (m, 1, 1))
    vel = np.zeros((m, 3), np.float32)
    inst, sem = np.zeros(m, np.uint32), np.zeros(m, np.uint8)
    for k, (iid, sid, c, size, yaw, pitch, roll, v) in enumerate(sorted(rows, key=lambda r: r[0])):
        # the box's orientation and centre in the frame
        R = R_wl @ rotation_matrix(yaw, pitch, roll)
        centre = R_wl @ np.asarray(c, float) + t_wl
        pose[k, :3, :3], pose[k, :3, 3] = R, centre
        # its heading: the box x axis seen from above in the frame
        boxes[k] = (*centre, *size, math.atan2(R[1, 0], R[0, 0]))
        vel[k] = R_wl @ np.asarray(v, float)
        inst[k], sem[k] = iid, sid
    return {"boxes": boxes, "box_pose": pose, "box_velocity": vel, "box_instance": inst, "box_semantic": sem}
