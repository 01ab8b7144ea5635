"""The rasterizer's documented ties (stages/sensors/raycast.py, "primary visibility by
rasterization"), told apart from errors by an independent float64 ray-triangle test: used by the
kernel tests on random scenes and by the real-frame test."""

from __future__ import annotations

import numpy as np

EDGE = 1e-4  # a ray this close to a triangle's edge (barycentric distance) is on it at float32 precision
SAME_DEPTH = 1e-6  # relative: two triangles this close in depth at a pixel are at equal depth


def exact_hit(V, tri, o, r):
    """Float64 reference of one ray and triangle: (inside, t, barycentric distance to the nearest edge)."""
    a, b, c = (V[k] - o for k in tri)
    s = np.array([np.cross(a, b) @ r, np.cross(b, c) @ r, np.cross(c, a) @ r])
    n = np.cross(b - a, c - a)
    den = n @ r
    t = (n @ a) / den if den != 0 else np.inf
    total = np.abs(s).sum()
    return bool(((s >= 0).all() or (s <= 0).all()) and total > 0 and t > 0), t, (np.abs(s).min() / total if total else 0.0)


def tie_pixels(V, F, rays, ours, ref):
    """Bool per pixel where the rasterizer's triangle ``ours`` and the caster's ``ref`` differ on a
    documented tie: both hit at equal depth (a shared edge, coplanar overlaps), or the ray passes
    within :data:`EDGE` of an edge of either triangle (a silhouette edge the two arithmetics round
    to different sides, the surface behind or the sky seen instead)."""
    out = np.zeros(len(ours), dtype=bool)
    V = np.asarray(V, dtype=np.float32).astype(np.float64)
    for i in np.flatnonzero(ours != ref):
        o, r = rays[i, :3].astype(np.float64), rays[i, 3:].astype(np.float64)
        hits = [exact_hit(V, F[f], o, r) for f in (ours[i], ref[i]) if f >= 0]
        on_edge = any(m < EDGE for _, _, m in hits)
        equal = len(hits) == 2 and abs(hits[0][1] - hits[1][1]) <= SAME_DEPTH * abs(hits[0][1])
        out[i] = on_edge or equal
    return out


def agree_with_the_caster(rs, cam, pose) -> int:
    """Assert that ``rs.first_hits`` (rasterization) gives open3d's triangle on every pixel of
    the camera but documented ties, and its depth where the triangle is the same; returns how
    many pixels differ."""
    from carlaocc.stages.sensors.raycast import rig_camera_rays

    origin, dirs = rig_camera_rays(cam, pose)
    rays = np.empty((len(dirs), 6), dtype=np.float32)
    rays[:, :3], rays[:, 3:] = origin, dirs
    t, face = rs.first_hits(cam, pose)
    t_ref, face_ref = rs.cast_rays(rays)
    ties = tie_pixels(rs.mesh.vertices, rs.mesh.faces, rays, face, face_ref)
    # the same triangle on every pixel but documented ties
    assert ((face == face_ref) | ties).all(), np.flatnonzero((face != face_ref) & ~ties)[:10]
    # misses are inf, hits carry the caster's depth to its float32 rounding (its t is float32
    # arithmetic; ours float64 rounded once)
    same = face == face_ref
    assert np.isinf(t[face < 0]).all()
    hit = same & (face >= 0)
    assert np.allclose(t[hit], t_ref[hit], rtol=2e-5, atol=0)
    return int((~same).sum())
