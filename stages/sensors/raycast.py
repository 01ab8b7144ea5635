"""Ray casting a frame's panoptic scene: camera depth/semantic/instance maps and LiDAR points.

The scene is one :class:`~carlaocc.stages.scenes.assembly.PanopticMesh` (per-triangle semantic, instance
and transparent flags) in the LiDAR frame (metres, x forward, y left, z up), cast through
open3d's Embree-backed :class:`open3d.t.geometry.RaycastingScene`; the cameras' first surfaces
are found by a compiled z-buffer rasterizer instead (:func:`rasterize_first_hits`, the same
triangle per pixel but for documented ties, 2-3x faster on one thread). A hit's triangle index
turns into labels by one vectorized lookup per map.

Cameras are pinhole, OpenCV optical frame (x right, y down, z forward), pixel ``(u, v)`` sampled
at its centre ``(u + 0.5, v + 0.5)``. Ray directions are scaled so their optical-axis component
is 1: the hit distance open3d returns is then the **planar depth** (z in the camera frame) the
reference dataset stores, with no division afterwards.

Conventions of the maps (:class:`CameraMaps`): depth float32 metres, 0 where no surface lies
within range (sky); semantic uint8 (CarlaOcc taxonomy), :data:`SKY` where no surface; instance
uint32, 0 for stuff and sky.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import math

import numpy as np
from numba import njit

from carlaocc.schemas.rig import CameraSpec, LidarSpec
from carlaocc.stages.scenes.assembly import PanopticMesh
from carlaocc.stages.voxelize.visibility import lidar_directions

SKY = 11  # taxonomy id of Sky: the label of pixels whose ray meets no surface
UNLABELLED = 0  # the empty label a simulator's semantic pass leaves on assets it does not render
_MISS = np.int64(-1)
_INVALID_ID = np.uint32(0xFFFFFFFF)  # open3d's RaycastingScene.INVALID_ID


@dataclass(frozen=True)
class CameraMaps:
    """One camera image's maps: planar depth (float32, m, 0 = no surface), semantic (uint8,
    :data:`SKY` where no surface) and instance (uint32, 0 = stuff or sky), all (H, W); ``face``
    (int64, (H, W), -1 = no surface) is the scene triangle each pixel sees, when known."""

    depth: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray | None
    face: np.ndarray | None = None


class RayScene:
    """A panoptic mesh ready for ray casting: an Embree BVH over its triangles (built once, in
    the constructor) plus the per-triangle labels.

    ``unlabelled`` (per triangle, optional) marks triangles a simulator's semantic pass leaves
    with the empty label (see :func:`render_camera`'s raw maps). The BVH is built on one thread
    whatever ``nthreads`` says, so its structure (and which of two triangles meeting at an edge a
    ray reports) cannot depend on the machine; ``nthreads`` applies to the casts.
    """

    def __init__(self, mesh: PanopticMesh, unlabelled: np.ndarray | None = None, nthreads: int = 0):
        import open3d as o3d  # 1.0 s to import (python -X importtime): paid only by tasks that cast rays

        self.mesh = mesh
        n = len(mesh.faces)
        self.unlabelled = (np.zeros(n, dtype=bool) if unlabelled is None
                           else np.ascontiguousarray(unlabelled, dtype=bool).reshape(-1))
        if len(self.unlabelled) != n:
            raise ValueError(f"unlabelled has {len(self.unlabelled)} entries for {n} triangles")
        # per-triangle lookups, with one extra slot at the end for "no hit" (index -1)
        self._semantic = np.append(mesh.semantic, np.uint8(SKY))
        self._instance = np.append(mesh.instance, np.uint32(0))
        self._transparent = np.append(mesh.transparent, False)
        self._color = np.concatenate([mesh.color, np.zeros((1, 3), np.uint8)])
        self._raw_semantic = np.append(np.where(self.unlabelled, np.uint8(UNLABELLED), mesh.semantic), np.uint8(SKY))
        self._raw_instance = np.append(np.where(self.unlabelled, np.uint32(0), mesh.instance), np.uint32(0))
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=1)
        self.triangle_count = n
        # the caster's geometry (float32 vertices) in float64, for the rasterizer (first_hits)
        self._vertices = np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)
        self._faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        if n:
            self._scene.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)),
            )

    def cast(self, origins: np.ndarray, directions: np.ndarray, nthreads: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """First hits of rays ``origins + t * directions`` (both (N, 3) or origins (3,); scene
        frame, metres): ``t`` (N,) float32 in units of each direction's length (``inf`` on a
        miss) and the hit triangle (N,) int64, -1 on a miss."""
        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        rays = np.empty((len(d), 6), dtype=np.float32)
        rays[:, :3] = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
        rays[:, 3:] = d
        return self.cast_rays(rays, nthreads)

    def cast_rays(self, rays: np.ndarray, nthreads: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`cast` of rays given as one (N, 6) float32 array ``[ox, oy, oz, dx, dy, dz]``."""
        import open3d as o3d  # 1.0 s to import (python -X importtime): paid only by tasks that cast rays

        n = len(rays)
        if self.triangle_count == 0 or n == 0:
            return np.full(n, np.inf, dtype=np.float32), np.full(n, _MISS)
        hit = self._scene.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, dtype=np.float32)),
                                    nthreads=nthreads)
        t = hit["t_hit"].numpy()
        prim = hit["primitive_ids"].numpy()
        face = prim.astype(np.int64)
        face[prim == _INVALID_ID] = _MISS
        return t, face

    def first_hits(self, camera: CameraSpec, camera_to_scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`cast_rays` of a camera's pixel rays (:func:`rig_camera_rays`, float32 as the
        caster gets them) by rasterization (:func:`rasterize_first_hits`): ``t`` (H*W,) float32
        (``inf`` on a miss) and the triangle (H*W,) int64 (-1 on a miss), row-major."""
        pose = np.ascontiguousarray(camera_to_scene, dtype=np.float64)
        _, _, rays = _camera_rays(camera, pose.tobytes())
        return rasterize_first_hits(self._vertices, self._faces, camera, pose, rays)

    def labels(self, face: np.ndarray, raw: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(semantic uint8, instance uint32) of hit triangles (-1 = miss: SKY, 0); ``raw`` gives
        the simulator's labels (unlabelled triangles -> 0, 0)."""
        if raw:
            return self._raw_semantic[face], self._raw_instance[face]
        return self._semantic[face], self._instance[face]

    def transparent(self, face: np.ndarray) -> np.ndarray:
        """Whether each hit triangle is transparent (False on a miss)."""
        return self._transparent[face]

    @property
    def semantic_table(self) -> np.ndarray:
        """uint8 per triangle, its semantic label, plus a last :data:`SKY` for index -1 (a miss):
        :meth:`labels` as a table, for compiled kernels; ``instance_table`` (uint32, last 0) and
        the ``*_raw`` tables (the simulator's labels, see :meth:`labels`) likewise."""
        return self._semantic

    @property
    def instance_table(self) -> np.ndarray:
        return self._instance

    @property
    def semantic_table_raw(self) -> np.ndarray:
        return self._raw_semantic

    @property
    def instance_table_raw(self) -> np.ndarray:
        return self._raw_instance

    @property
    def transparent_table(self) -> np.ndarray:
        """Bool per triangle, whether it is transparent, plus a last False for index -1 (a miss):
        :meth:`transparent` as a table, for compiled kernels."""
        return self._transparent

    def color(self, face: np.ndarray) -> np.ndarray:
        """Base colour (uint8 RGB, (N, 3)) of each hit triangle (black on a miss)."""
        return self._color[face]


@lru_cache(maxsize=32)
def _optical_directions(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    # pixel centres -> ((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1), row-major (v outer, u inner)
    u = (np.arange(width, dtype=np.float64) + 0.5 - cx) / fx
    v = (np.arange(height, dtype=np.float64) + 0.5 - cy) / fy
    d = np.empty((height, width, 3), dtype=np.float64)
    d[..., 0] = u[None, :]
    d[..., 1] = v[:, None]
    d[..., 2] = 1.0
    d = d.reshape(-1, 3)
    d.setflags(write=False)
    return d


def camera_ray_bundle(camera: CameraSpec, camera_to_scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's pixel rays in the scene frame: its optical centre (3,) and (H*W, 3)
    directions, row-major, each with unit component along the optical axis (so a hit distance
    is the planar depth). ``camera_to_scene`` is the 4x4 pose of the OpenCV optical frame."""
    K = np.asarray(camera.intrinsics, dtype=np.float64)
    T = np.asarray(camera_to_scene, dtype=np.float64)
    d = _optical_directions(camera.width, camera.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    # rotate into the scene frame; the origin is the pose's translation
    return T[:3, 3].copy(), d @ T[:3, :3].T


@lru_cache(maxsize=16)
def _camera_rays(camera: CameraSpec, pose_bytes: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # a rig camera's rays are the same every frame (the scene is in the LiDAR frame): build once
    origin, dirs = camera_ray_bundle(camera, np.frombuffer(pose_bytes, dtype=np.float64).reshape(4, 4))
    rays = np.empty((len(dirs), 6), dtype=np.float32)
    rays[:, :3] = origin
    rays[:, 3:] = dirs
    for a in (origin, dirs, rays):
        a.setflags(write=False)
    return origin, dirs, rays


def rig_camera_rays(camera: CameraSpec, camera_to_scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`camera_ray_bundle` of a rig camera, computed once per (camera, pose) in this
    process and returned read-only: a rig's cameras see the same rays every frame (the scene is
    in the LiDAR frame), and the (H*W, 3) rotation is a BLAS product not worth redoing per frame."""
    origin, dirs, _ = _camera_rays(camera, np.ascontiguousarray(camera_to_scene, dtype=np.float64).tobytes())
    return origin, dirs


def covered_pixels(mesh: PanopticMesh, camera: CameraSpec, camera_to_scene: np.ndarray, near: float = 1e-3) -> np.ndarray:
    """Bool (H, W): pixels whose ray may meet a triangle of ``mesh`` (scene frame), a superset
    from each triangle's screen bounding box. Rays outside it miss the mesh for certain, so a
    small mesh (the rectification's compact mesh) is cast only where it can be seen."""
    H, W = camera.height, camera.width
    K = np.asarray(camera.intrinsics, dtype=np.float64)
    if len(mesh.faces) == 0:
        return np.zeros((H, W), dtype=bool)
    # 1. vertices into the OpenCV camera frame
    T = np.linalg.inv(np.asarray(camera_to_scene, dtype=np.float64))
    P = mesh.vertices @ T[:3, :3].T + T[:3, 3]
    tri = P[mesh.faces]  # (M, 3 corners, 3)
    z = tri[..., 2]
    # 2. the part of each triangle in front of the near plane: its corners there, plus the points
    #    where its edges cross the plane (triangles wholly behind the camera drop out)
    a, b = tri, np.roll(tri, -1, axis=1)
    za, zb = a[..., 2], b[..., 2]
    cross = (za > near) != (zb > near)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(cross, (near - za) / (zb - za), 0.0)
    hit = a + s[..., None] * (b - a)
    pts = np.concatenate([tri, hit], axis=1)  # (M, 6, 3)
    ok = np.concatenate([z > near, cross], axis=1)
    zz = np.where(ok, np.maximum(pts[..., 2], near), 1.0)
    u = K[0, 0] * pts[..., 0] / zz + K[0, 2]
    v = K[1, 1] * pts[..., 1] / zz + K[1, 2]
    # 3. screen boxes in pixel indices (a pixel is sampled at its centre, index + 0.5), clipped
    umin = np.where(ok, u, np.inf).min(axis=1)
    umax = np.where(ok, u, -np.inf).max(axis=1)
    vmin = np.where(ok, v, np.inf).min(axis=1)
    vmax = np.where(ok, v, -np.inf).max(axis=1)
    i0 = np.clip(np.floor(umin - 0.5) - 1, 0, W).astype(np.int64)
    i1 = np.clip(np.ceil(umax - 0.5) + 2, 0, W).astype(np.int64)
    j0 = np.clip(np.floor(vmin - 0.5) - 1, 0, H).astype(np.int64)
    j1 = np.clip(np.ceil(vmax - 0.5) + 2, 0, H).astype(np.int64)
    keep = ok.any(axis=1) & (i1 > i0) & (j1 > j0)
    # 4. union of the boxes: a 2D difference array, summed along both axes
    diff = np.zeros((H + 1, W + 1), dtype=np.int64)
    np.add.at(diff, (j0[keep], i0[keep]), 1)
    np.add.at(diff, (j0[keep], i1[keep]), -1)
    np.add.at(diff, (j1[keep], i0[keep]), -1)
    np.add.at(diff, (j1[keep], i1[keep]), 1)
    return np.cumsum(np.cumsum(diff, axis=0), axis=1)[:H, :W] > 0


# -- primary visibility by rasterization ---------------------------------------------------------------
# A pixel's ray o + t r (o the camera centre, r its float32 direction, both as the caster gets
# them) meets the triangle (a, b, c) (float32 vertices, taken relative to o in float64) when the
# three signed volumes (a x b) . r, (b x c) . r, (c x a) . r have one sign (zeros included: a ray
# through an edge or a corner meets both triangles sharing it), at t = (n . a) / (n . r) with n the
# triangle's normal, if t > 0. Each pixel keeps its nearest triangle; of two at the same t (float64)
# the one of lower index. Only the pixels of each triangle's screen box are tested. Where this
# differs from the caster (open3d's Embree, float32 arithmetic): rays through a shared edge or
# corner (the caster reports either triangle, or at times neither: the surface behind), two
# triangles at equal depth (coplanar overlaps), and the depth's last float32 bits (the caster's t
# is computed in float32, ours in float64 and rounded once).
NEAR = 1e-6  # m: triangles' parts closer to the camera plane than this are not drawn


@njit(cache=True, nogil=True)
def _screen_polygon(p, fx, fy, cx, cy, qx, qy):
    # the triangle's part in front of the camera plane z = NEAR (camera frame ``p``, (3, 3)):
    # one plane's clipping in order (Sutherland-Hodgman), projected to pixel coordinates in
    # ``qx``, ``qy``; returns its corner count (0: wholly behind; at most 4)
    m = 0
    for k in range(3):
        a, b = p[k], p[(k + 1) % 3]
        if a[2] > NEAR:
            qx[m], qy[m] = fx * a[0] / a[2] + cx, fy * a[1] / a[2] + cy
            m += 1
        if (a[2] > NEAR) != (b[2] > NEAR):
            s = (NEAR - a[2]) / (b[2] - a[2])
            qx[m] = fx * (a[0] + s * (b[0] - a[0])) / NEAR + cx
            qy[m] = fy * (a[1] + s * (b[1] - a[1])) / NEAR + cy
            m += 1
    return m


@njit(cache=True, nogil=True)
def _band_span(qx, qy, m, y0, y1):
    # x extent of the convex polygon within the band y0 <= y <= y1 (the band clamped into the
    # polygon's height: a row a rounding error outside still gets the nearest part): its corners
    # inside the band and its edges' crossings of the band's two lines
    ymin, ymax = qy[0], qy[0]
    for k in range(1, m):
        ymin, ymax = min(ymin, qy[k]), max(ymax, qy[k])
    y0, y1 = min(max(y0, ymin), ymax), min(max(y1, ymin), ymax)
    lo, hi = math.inf, -math.inf
    for k in range(m):
        xa, ya, xb, yb = qx[k], qy[k], qx[(k + 1) % m], qy[(k + 1) % m]
        if y0 <= ya <= y1:
            lo, hi = min(lo, xa), max(hi, xa)
        for y in (y0, y1):
            if ya != yb and min(ya, yb) <= y <= max(ya, yb):
                x = xa + (y - ya) / (yb - ya) * (xb - xa)
                lo, hi = min(lo, x), max(hi, x)
    return lo, hi


# The screen spans only choose which pixels the exact test above sees: a pixel's float32 ray passes
# within ~1e-4 pixel of its centre (the direction's float32 rounding, 2**-24 relative, times a
# focal length of ~1,000 pixels), so the polygon's extent over a band of rows +-0.01 pixel around
# the row's centres, widened by 0.01 pixel, holds every pixel whose ray can meet the triangle
# (whatever its edges' slopes); the span was a whole pixel wider on each side before.
SPAN_MARGIN = 0.01  # pixels


@njit(cache=True, nogil=True)
def _rasterize(V, F, o, to_camera, fx, fy, cx, cy, W, H, rays, best_t, best_f):
    p = np.empty((3, 3))
    qx, qy = np.empty(4), np.empty(4)
    for f in range(len(F)):
        # 1. the corners relative to the ray origin (scene frame) and in the camera frame
        a0, a1, a2 = V[F[f, 0], 0] - o[0], V[F[f, 0], 1] - o[1], V[F[f, 0], 2] - o[2]
        b0, b1, b2 = V[F[f, 1], 0] - o[0], V[F[f, 1], 1] - o[1], V[F[f, 1], 2] - o[2]
        c0, c1, c2 = V[F[f, 2], 0] - o[0], V[F[f, 2], 1] - o[1], V[F[f, 2], 2] - o[2]
        for k, (x, y, z) in enumerate(((a0, a1, a2), (b0, b1, b2), (c0, c1, c2))):
            for r in range(3):
                p[k, r] = to_camera[r, 0] * x + to_camera[r, 1] * y + to_camera[r, 2] * z
        # 2. its screen polygon and the image rows whose centres (pixel j is sampled at j + 0.5)
        #    it spans, widened by SPAN_MARGIN against rounding; off screen: next
        m = _screen_polygon(p, fx, fy, cx, cy, qx, qy)
        if m == 0:
            continue
        vmin, vmax = qy[:m].min(), qy[:m].max()
        if not (vmax >= -1.0 and vmin <= H + 1.0 and qx[:m].max() >= -1.0 and qx[:m].min() <= W + 1.0):
            continue
        j0 = max(math.ceil(vmin - 0.5 - SPAN_MARGIN), 0)
        j1 = min(math.floor(vmax - 0.5 + SPAN_MARGIN), H - 1)
        if j0 > j1:
            continue
        # 3. the normal (degenerate triangles are never hit) and the plane's offset n . a
        n0 = (b1 - a1) * (c2 - a2) - (b2 - a2) * (c1 - a1)
        n1 = (b2 - a2) * (c0 - a0) - (b0 - a0) * (c2 - a2)
        n2 = (b0 - a0) * (c1 - a1) - (b1 - a1) * (c0 - a0)
        if n0 == 0.0 and n1 == 0.0 and n2 == 0.0:
            continue
        na = n0 * a0 + n1 * a1 + n2 * a2
        # 4. the edges' planes through the origin: a x b, b x c, c x a
        e00, e01, e02 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        e10, e11, e12 = b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0
        e20, e21, e22 = c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0
        # 5. per row, the pixels of the polygon's span (widened by SPAN_MARGIN): inside all three
        #    planes (one sign), in front, nearest
        for v in range(j0, j1 + 1):
            lo, hi = _band_span(qx, qy, m, v + 0.5 - SPAN_MARGIN, v + 0.5 + SPAN_MARGIN)
            i0, i1 = max(math.ceil(lo - 0.5 - SPAN_MARGIN), 0), min(math.floor(hi - 0.5 + SPAN_MARGIN), W - 1)
            for u in range(i0, i1 + 1):
                idx = v * W + u
                r0, r1, r2 = np.float64(rays[idx, 3]), np.float64(rays[idx, 4]), np.float64(rays[idx, 5])
                s0 = e00 * r0 + e01 * r1 + e02 * r2
                s1 = e10 * r0 + e11 * r1 + e12 * r2
                s2 = e20 * r0 + e21 * r1 + e22 * r2
                if not ((s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0) or (s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0)):
                    continue
                den = n0 * r0 + n1 * r1 + n2 * r2
                if den == 0.0:
                    continue
                t = na / den
                if t > 0.0 and t < best_t[idx]:  # strictly nearer: the lower index keeps a tie
                    best_t[idx] = t
                    best_f[idx] = f


def rasterize_first_hits(vertices: np.ndarray, faces: np.ndarray, camera: CameraSpec, camera_to_scene: np.ndarray,
                         rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits of a camera's pixel rays ``rays`` ((H*W, 6) float32 ``[origin, direction]``,
    row-major, one origin: :func:`rig_camera_rays`) on triangles ``faces`` of ``vertices``
    (float64 values of the caster's float32 vertices; scene frame, metres), by rasterization:
    ``t`` (H*W,) float32 in units of each direction's length (``inf`` on a miss) and the
    triangle (H*W,) int64 (-1 on a miss). The module's notes above give the rule and where it
    may differ from the caster."""
    H, W = camera.height, camera.width
    K = np.asarray(camera.intrinsics, dtype=np.float64)
    T = np.asarray(camera_to_scene, dtype=np.float64)
    best_t = np.full(H * W, np.inf)
    best_f = np.full(H * W, _MISS)
    if len(faces):
        # the rays' common origin as the caster sees it (float32); the scene -> camera rotation
        o = rays[0, :3].astype(np.float64)
        _rasterize(vertices, faces, o, np.ascontiguousarray(T[:3, :3].T), K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H,
                   rays, best_t, best_f)
    return best_t.astype(np.float32), best_f


@njit(cache=True, nogil=True)
def _hit_maps(t, face, max_depth, semantic, instance):
    # one pass over a camera's hits: a miss (face -1) or a hit beyond ``max_depth`` (in t's
    # dtype, as numpy compares an array with a Python float) becomes no surface (face -1, depth
    # 0); depth float32, labels from the per-triangle tables (their last slot: no surface)
    n = len(face)
    depth = np.empty(n, dtype=np.float32)
    sem = np.empty(n, dtype=semantic.dtype)
    inst = np.empty(n, dtype=instance.dtype)
    for i in range(n):
        f = face[i]
        if f < 0 or not t[i] <= max_depth:
            face[i] = -1
            depth[i] = 0.0
            sem[i], inst[i] = semantic[-1], instance[-1]
        else:
            depth[i] = np.float32(t[i])
            sem[i], inst[i] = semantic[f], instance[f]
    return depth, sem, inst


def render_camera(scene: RayScene, camera: CameraSpec, camera_to_scene: np.ndarray, max_depth: float = np.inf,
                  raw: bool = False, see_through: bool = True, nthreads: int = 0,
                  max_layers: int = 8, pixels: np.ndarray | None = None) -> tuple[CameraMaps, CameraMaps | None]:
    """The clean maps of one camera (the first surface of any kind along each pixel ray) and,
    with ``raw``, the maps a simulator delivers (the first *opaque* surface, with the
    simulator's labels: unlabelled triangles give 0/0).

    Depth beyond ``max_depth`` (planar, m) counts as no surface. Raw rays whose first hit is
    transparent are continued from just past it (1e-4 m) through at most ``max_layers`` layers
    of glass (a car seen through both its side windows is two); a ray still on glass after that
    keeps the last layer's depth. ``see_through=False`` models a renderer that draws glass into
    its depth and semantic passes (raw rays stop on it; only the unlabelled rule applies).
    ``pixels`` (bool (H, W), e.g. :func:`covered_pixels`) keeps only those rays; the others
    count as misses. The first surface is found by rasterization (:func:`rasterize_first_hits`:
    the caster's triangle but for rays through shared edges, equal depths, and the depth's last
    float32 bits); rays continued through glass are cast.
    """
    H, W = camera.height, camera.width
    pose = np.ascontiguousarray(camera_to_scene, dtype=np.float64)
    origin, dirs, rays = _camera_rays(camera, pose.tobytes())
    # 1. first hits of every pixel ray by rasterization (:meth:`RayScene.first_hits`), or of the
    #    requested ones
    t, face = scene.first_hits(camera, pose)
    if pixels is not None:
        off = ~np.asarray(pixels, dtype=bool).reshape(-1)
        t[off], face[off] = np.inf, _MISS
    # misses and hits beyond range: no surface (face -1, depth 0, the sky's labels)
    depth, sem, inst = _hit_maps(t, face, t.dtype.type(max_depth), scene.semantic_table, scene.instance_table)
    clean = CameraMaps(depth.reshape(H, W), sem.reshape(H, W), inst.reshape(H, W), face.reshape(H, W))
    if not raw:
        return clean, None
    # 2. continue the rays that stopped on glass, from just past the hit, until an opaque surface
    t_raw, face_raw = np.where(face < 0, np.inf, t.astype(np.float64)), face.copy()
    todo = np.flatnonzero(scene.transparent(face_raw)) if see_through else np.zeros(0, dtype=np.int64)
    if len(todo):
        # the rays on glass cast again from the camera: the continuation starts from the caster's
        # own hit (its float32 t, which the rasterizer's may miss by an ulp), so the layers behind
        # are found as before (rays continued a rounding error apart can part ways between two
        # close layers of glass)
        t_cast, f_cast = scene.cast_rays(rays[todo], nthreads=nthreads)
        t_raw[todo], face_raw[todo] = t_cast, f_cast
        todo = todo[scene.transparent(f_cast)]
    step = 1e-4
    for _ in range(max_layers):
        if len(todo) == 0:
            break
        start = t_raw[todo] + step
        t2, f2 = scene.cast(origin + start[:, None] * dirs[todo], dirs[todo], nthreads=nthreads)
        t_raw[todo] = start + t2  # inf stays inf on a miss
        face_raw[todo] = f2
        todo = todo[scene.transparent(f2)]
    depth_raw, sem_r, inst_r = _hit_maps(t_raw, face_raw, t_raw.dtype.type(max_depth), scene.semantic_table_raw,
                                         scene.instance_table_raw)
    raw_maps = CameraMaps(depth_raw.reshape(H, W), sem_r.reshape(H, W), inst_r.reshape(H, W), face_raw.reshape(H, W))
    return clean, raw_maps


@lru_cache(maxsize=8)
def _lidar_beams(lidar: LidarSpec) -> tuple[np.ndarray, np.ndarray]:
    d = lidar_directions(lidar)
    steps = len(d) // lidar.channels
    channel = np.repeat(np.arange(lidar.channels, dtype=np.uint8), steps)
    d.setflags(write=False)
    channel.setflags(write=False)
    return d, channel


def lidar_scan(scene: RayScene, lidar: LidarSpec, nthreads: int = 0) -> dict[str, np.ndarray]:
    """One sweep of the rig's LiDAR from the scene frame's origin (the scene is in the LiDAR
    frame): the beams of :func:`~carlaocc.stages.voxelize.visibility.lidar_directions` (channels x
    ``points_per_frame // channels`` azimuths), first hit of any surface within ``range_m``.

    Returns columns x, y, z, distance (float32, m, LiDAR frame), semantic (uint8), instance
    (uint32) and channel (uint8, 0 = top beam) of the beams that hit; beams that hit nothing in
    range return no point (as CARLA's ray-cast LiDAR).
    """
    d, channel = _lidar_beams(lidar)
    t, face = scene.cast(np.zeros(3), d, nthreads=nthreads)
    # unit directions: the hit distance is the range
    hit = np.flatnonzero(t <= lidar.range_m)
    p = (d[hit] * t[hit, None]).astype(np.float32)
    sem, inst = scene.labels(face[hit])
    return {"x": p[:, 0].copy(), "y": p[:, 1].copy(), "z": p[:, 2].copy(), "distance": t[hit].astype(np.float32),
            "semantic": sem, "instance": inst, "channel": channel[hit].copy()}
