"""Geometry helpers shared by the stages: rigid transforms, mesh measures and checks.

Small pure numpy functions in the trimesh style over ``(N, 3)`` float64 vertices and ``(M, 3)``
int64 faces (the mesh types themselves, :class:`~carlaocc.schemas.meshes.MeshPart` and friends,
live in ``carlaocc.schemas.meshes``). Units are metres; poses are 4x4 float64 homogeneous matrices mapping
a source frame into a target frame (``p_target = T @ p_source``).
"""

from __future__ import annotations

import hashlib

import numpy as np


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 homogeneous transform to (N, 3) points; returns (N, 3) float64."""
    # rotate-scale by the upper 3x3, then translate
    pts = np.asarray(points, dtype=np.float64)
    return pts @ np.asarray(T, dtype=np.float64)[:3, :3].T + np.asarray(T, dtype=np.float64)[:3, 3]


def pose_matrix(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """4x4 pose of a frame at (x, y, z) m rotated by ``yaw`` rad about +Z (right-handed)."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, z)
    return T


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
