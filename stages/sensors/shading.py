"""Camera RGB from the frame's panoptic scene: the ray caster's hits shaded with the parts' base
colours, a sun (Lambert + cast shadows), ambient light and a sky gradient.

Frames and units: the scene frame is the frame's LiDAR frame (metres); ``sun`` and ``up`` are
unit vectors in it (towards the sun; the world's up). Colours are RGB 0-255.

The model, per pixel:

1. the first opaque surface along the pixel ray (the raw maps' hit: glass is looked through);
   no surface: the sky, blended from :data:`SKY_HORIZON` to :data:`SKY_ZENITH` by the ray's
   elevation;
2. its base colour: the part's material colour (ADMesh ``parts.color``); parts that carry only
   the default grey (town ground meshes, sources without materials) take their class's
   :data:`CLASS_BASE` colour (asphalt, paving, grass, paint...); a textured part's colour is its
   texture at the hit (barycentric coordinates of the hit in its triangle interpolate the
   corners' texture coordinates; the nearest texel, repeating) times its material colour;
3. shading ``ambient + (1 - ambient) * max(0, n . sun) * lit``, with ``n`` the triangle's normal
   turned towards the camera and ``lit`` whether a ray from the point towards the sun escapes the
   scene (glass does not cast shadows);
4. glass in front of it (the clean maps' first hit is transparent): tinted by
   :data:`GLASS` at :data:`GLASS_OPACITY`.

Everything is deterministic: the same scene and sun give the same bytes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from carlaocc.schemas import taxonomy

__all__ = ["CLASS_BASE", "DEFAULT_GREY", "GLASS", "GLASS_OPACITY", "SKY_HORIZON", "SKY_ZENITH", "barycentric",
           "base_colours", "face_normals", "reference_rgb", "reference_shade", "render_rgb", "sample_texture", "shade",
           "sun_direction"]

SKY_HORIZON = np.array([206.0, 222.0, 236.0])
SKY_ZENITH = np.array([92.0, 142.0, 207.0])
GLASS = np.array([120.0, 150.0, 165.0])
GLASS_OPACITY = 0.35
DEFAULT_GREY = (200, 200, 200)
SHADOW_OFFSET = 2e-3  # m: shadow rays start this far off the surface (no self-shadowing)

# what an uncoloured part of a class looks like (the town's ground meshes carry no colour)
CLASS_BASE: dict[str, tuple[int, int, int]] = {
    "Road": (72, 72, 76), "RoadLine": (226, 224, 214), "Sidewalk": (168, 165, 158), "Terrain": (98, 126, 64),
    "Ground": (130, 118, 100), "Water": (62, 92, 122), "RailTrack": (92, 82, 72), "Bridge": (142, 137, 130),
    "Building": (178, 168, 152), "Wall": (160, 152, 142), "Fence": (140, 128, 108), "GuardRail": (172, 172, 178),
    "Pole": (118, 118, 124), "TrafficLight": (52, 56, 60), "TrafficSign": (190, 60, 50), "Vegetation": (72, 112, 52),
    "Static": (132, 122, 112), "Dynamic": (128, 110, 90), "Other": (128, 128, 128), "Rock": (128, 120, 110),
}  # fmt: skip


def _class_table() -> np.ndarray:
    table = np.array([DEFAULT_GREY] * 256, dtype=np.float64)
    for name, rgb in CLASS_BASE.items():
        table[taxonomy.by_name(name).id] = rgb
    return table


_CLASS_TABLE = _class_table()


def sun_direction(azimuth_deg: float, elevation_deg: float, world_to_scene: np.ndarray) -> np.ndarray:
    """Unit vector towards the sun in the scene frame: ``azimuth`` counter-clockwise from the
    world's +x (east in CARLA's maps) and ``elevation`` above the horizon, both degrees, rotated by
    the 3x3 (or 4x4) ``world_to_scene``."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    s = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    R = np.asarray(world_to_scene, dtype=np.float64)[:3, :3]
    return R @ s


def base_colours(color: np.ndarray, semantic: np.ndarray) -> np.ndarray:
    """(N, 3) float base colours: each triangle's colour, or its class's :data:`CLASS_BASE`
    colour where it carries only the default grey."""
    c = np.asarray(color, dtype=np.float64).reshape(-1, 3)
    grey = np.all(np.asarray(color).reshape(-1, 3) == DEFAULT_GREY, axis=1)
    return np.where(grey[:, None], _CLASS_TABLE[np.asarray(semantic, dtype=np.int64).reshape(-1)], c)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals (M, 3) float32 of the triangles (right-hand rule; degenerate ones (0, 0, 1))."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    n[norm == 0] = (0.0, 0.0, 1.0)
    norm[norm == 0] = 1.0
    return (n / norm[:, None]).astype(np.float32)


def barycentric(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric weights of points ``p`` (N, 3) in triangles ``tri`` (N, 3, 3), same
    frame; points off a triangle's plane are projected onto it, weights clipped to the triangle
    (a hit on an edge may land a rounding error outside) and summing to 1."""
    tri = np.asarray(tri, dtype=np.float64)
    a = tri[:, 0]
    e1, e2, q = tri[:, 1] - a, tri[:, 2] - a, np.asarray(p, dtype=np.float64) - a
    # the 2x2 normal equations of q = v * e1 + w * e2 (least squares: the plane's projection)
    d11, d12, d22 = (np.einsum("ij,ij->i", a_, b_) for a_, b_ in ((e1, e1), (e1, e2), (e2, e2)))
    q1, q2 = np.einsum("ij,ij->i", q, e1), np.einsum("ij,ij->i", q, e2)
    det = d11 * d22 - d12 * d12
    det = np.where(det == 0.0, 1.0, det)  # degenerate triangles: the first corner
    v = (d22 * q1 - d12 * q2) / det
    w = (d11 * q2 - d12 * q1) / det
    out = np.clip(np.stack([1.0 - v - w, v, w], axis=1), 0.0, None)
    s = out.sum(1, keepdims=True)
    return np.where(s > 0, out / np.where(s > 0, s, 1.0), np.array([1.0, 0.0, 0.0]))


def sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 3) float colours of ``image`` (H, W, 3) at texture coordinates ``uv`` (N, 2): u right,
    v up from the bottom-left corner, repeating outside [0, 1]; the nearest texel."""
    H, W = image.shape[:2]
    u = np.mod(uv[:, 0], 1.0)
    v = np.mod(uv[:, 1], 1.0)
    x = np.minimum((u * W).astype(np.int64), W - 1)
    y = np.minimum(((1.0 - v) * H).astype(np.int64), H - 1)  # row 0 is the image's top
    return image[y, x].astype(np.float32)


def textured_base(mesh, f: np.ndarray, points: np.ndarray, base: np.ndarray) -> np.ndarray:
    """(N, 3) float32 base colours of hits at ``points`` (N, 3, the mesh's frame) on triangles
    ``f``: ``base[f]``, times the texture at the hit where the triangle has one (``mesh`` a
    :class:`~carlaocc.stages.scenes.assembly.PanopticMesh`)."""
    out = base[f].astype(np.float32, copy=True)
    if getattr(mesh, "texture", None) is None or not len(f):
        return out
    slot = mesh.texture[f]
    for k in np.unique(slot[slot >= 0]):
        sel = np.flatnonzero(slot == k)
        ff = f[sel]
        # where the hit lies in its triangle, and so in the texture
        w = barycentric(mesh.vertices[mesh.faces[ff]], points[sel])
        uv = np.einsum("nk,nkj->nj", w, mesh.uv[ff].astype(np.float64))
        out[sel] *= sample_texture(mesh.images[k], uv) / np.float32(255.0)
    return out


# -- the compiled per-pixel kernels ------------------------------------------------------------------
# Float32 arithmetic in the numpy reference's order (:func:`reference_shade`,
# :func:`reference_rgb`), except the two dot products n . d and n . sun, summed here left to right
# where numpy's einsum / BLAS may order or fuse them otherwise: a colour can then differ in its
# last float32 bit, and a byte by one where that bit crosses a rounding boundary (tests count them).


@njit(cache=True, nogil=True)
def _sunlit(face, t, dirs, normals, sun, origin, offset, sign, lambert, rays, lit_index):
    """Step 2 and 3's first half for every hit pixel: the normal's sign against the ray, the
    Lambert term, and a shadow ray (origin just off the surface, towards the sun) for each pixel
    facing the sun. Returns how many shadow rays were written."""
    k = 0
    s0, s1, s2 = np.float32(sun[0]), np.float32(sun[1]), np.float32(sun[2])
    for i in range(len(face)):
        f = face[i]
        if f < 0:
            continue
        d0, d1, d2 = np.float32(dirs[i, 0]), np.float32(dirs[i, 1]), np.float32(dirs[i, 2])
        n0, n1, n2 = normals[f, 0], normals[f, 1], normals[f, 2]
        # the normal turned towards the camera: its sign against the ray
        sg = np.float32(-1.0) if (n0 * d0 + n1 * d1) + n2 * d2 > 0 else np.float32(1.0)
        lam = min(max(sg * ((n0 * s0 + n1 * s1) + n2 * s2), np.float32(0.0)), np.float32(1.0))
        sign[i], lambert[i] = sg, lam
        if lam > 0:
            # the hit point (float64, as numpy promotes the float64 origin), pushed off the surface
            off = np.float32(offset * sg)
            ti = t[i]
            rays[k, 0] = np.float32(origin[0] + ti * d0 + off * n0)
            rays[k, 1] = np.float32(origin[1] + ti * d1 + off * n1)
            rays[k, 2] = np.float32(origin[2] + ti * d2 + off * n2)
            rays[k, 3], rays[k, 4], rays[k, 5] = s0, s1, s2
            lit_index[k] = i
            k += 1
    return k


@njit(cache=True, nogil=True)
def _lit(lit_index, blocker, transparent, lit):
    # a sunlit point is lit when its shadow ray escapes or meets only glass
    for k in range(len(lit_index)):
        b = blocker[k]
        lit[lit_index[k]] = b < 0 or transparent[b]


@njit(cache=True, nogil=True)
def _light(face, lambert, lit, colour, base, ambient, out):
    # step 3's second half: ambient + (1 - ambient) * lambert * lit times the base colour
    # (``colour`` per hit pixel when textured, else empty and ``base`` per triangle)
    amb = np.float32(ambient)
    direct = np.float32(1.0 - ambient)
    textured = len(colour) > 0
    j = 0
    for i in range(len(face)):
        f = face[i]
        if f < 0:
            continue
        light = amb + (direct * lambert[i]) * (np.float32(1.0) if lit[i] else np.float32(0.0))
        for c in range(3):
            out[i, c] = (colour[j, c] if textured else base[f, c]) * light
        j += 1


@njit(cache=True, nogil=True)
def _tint_and_round(rgb, front, face, transparent, keep, tint, out):
    # step 4: glass in front of the opaque surface tints it; then round half to even to bytes
    for i in range(len(face)):
        g = front[i] >= 0 and transparent[front[i]] and front[i] != face[i]
        for c in range(3):
            x = rgb[i, c]
            if g:
                x = keep * x + tint[c]
            out[i, c] = np.uint8(min(max(np.rint(x), np.float32(0.0)), np.float32(255.0)))


@njit(cache=True, nogil=True)
def _sky_elevation(face, dirs, up, h):
    # step 1's first half, on the pixels without a surface: the sine of the ray's elevation,
    # clipped to [0, 1] (float32: the dot product left to right, the norm's sum of squares too)
    u0, u1, u2 = np.float32(up[0]), np.float32(up[1]), np.float32(up[2])
    j = 0
    for i in range(len(face)):
        if face[i] >= 0:
            continue
        d0, d1, d2 = np.float32(dirs[i, 0]), np.float32(dirs[i, 1]), np.float32(dirs[i, 2])
        norm = np.float32(math.sqrt((d0 * d0 + d1 * d1) + d2 * d2))
        h[j] = min(max(((d0 * u0 + d1 * u1) + d2 * u2) / norm, np.float32(0.0)), np.float32(1.0))
        j += 1


@njit(cache=True, nogil=True)
def _sky_colour(face, h, horizon, zenith_minus_horizon, out):
    # step 1's second half: horizon to zenith by the elevation's power
    j = 0
    for i in range(len(face)):
        if face[i] >= 0:
            continue
        for c in range(3):
            out[i, c] = horizon[c] + zenith_minus_horizon[c] * h[j]
        j += 1


def shade(scene, origin: np.ndarray, dirs: np.ndarray, t: np.ndarray, face: np.ndarray, sun: np.ndarray,
          up: np.ndarray, ambient: float, normals: np.ndarray, base: np.ndarray | None = None,
          nthreads: int = 0) -> np.ndarray:
    """(N, 3) float32 colours of rays ``origin + t * dirs`` hitting triangles ``face`` (-1: sky)
    of ``scene`` (a :class:`~carlaocc.stages.sensors.raycast.RayScene`), lit by ``sun``;
    ``normals`` and ``base`` (per triangle, :func:`face_normals` and :func:`base_colours`; base
    computed here when None) are computed once per frame for all cameras. Compiled per pixel;
    :func:`reference_shade` is the same model in numpy."""
    face = np.ascontiguousarray(face, dtype=np.int64).reshape(-1)
    n_rays = len(face)
    out = np.empty((n_rays, 3), dtype=np.float32)
    hit = face >= 0
    n_hit = int(np.count_nonzero(hit))
    dirs = np.asarray(dirs).reshape(-1, 3)
    # 1. the sky: horizon to zenith by the ray's elevation (its power by numpy's own float32 pow,
    #    as the reference computes it)
    h = np.empty(n_rays - n_hit, dtype=np.float32)
    _sky_elevation(face, dirs, np.asarray(up, dtype=np.float64), h)
    _sky_colour(face, h ** 0.6, SKY_HORIZON.astype(np.float32), (SKY_ZENITH - SKY_HORIZON).astype(np.float32), out)
    if not n_hit:
        return out
    if base is None:
        base = base_colours(scene.mesh.color, scene.mesh.semantic).astype(np.float32)
    t = np.ascontiguousarray(t).reshape(-1)
    normals = np.ascontiguousarray(normals, dtype=np.float32)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    # 2. the normal turned towards the camera and the Lambert term; 3. shadow rays from the sunlit
    sign = np.zeros(n_rays, dtype=np.float32)
    lambert = np.zeros(n_rays, dtype=np.float32)
    rays = np.empty((n_hit, 6), dtype=np.float32)
    lit_index = np.empty(len(rays), dtype=np.int64)
    k = _sunlit(face, t, dirs, normals, np.asarray(sun, dtype=np.float64), origin, SHADOW_OFFSET, sign, lambert,
                rays, lit_index)
    lit = np.zeros(n_rays, dtype=bool)
    if k:
        _, blocker = scene.cast_rays(rays[:k], nthreads=nthreads)
        _lit(lit_index[:k], blocker, scene.transparent_table, lit)
    if getattr(scene.mesh, "texture", None) is None:
        colour = np.zeros((0, 3), dtype=np.float32)
    else:  # the hits' points, where the texture is read
        f = face[hit]
        colour = textured_base(scene.mesh, f, origin + t[hit][:, None].astype(np.float64)
                               * np.asarray(dirs[hit], dtype=np.float32), base)
    _light(face, lambert, lit, colour, np.ascontiguousarray(base, dtype=np.float32), float(ambient), out)
    return out


def render_rgb(scene, origin: np.ndarray, dirs: np.ndarray, clean, raw, sun: np.ndarray, up: np.ndarray,
               ambient: float = 0.35, normals: np.ndarray | None = None, base: np.ndarray | None = None,
               nthreads: int = 0) -> np.ndarray:
    """(H, W, 3) uint8 image of one camera from its maps: ``clean`` (first surface) and ``raw``
    (first opaque surface; None: the clean one), :class:`CameraMaps` with ``face`` set; ``origin``
    and ``dirs`` the camera's rays (unit component along the optical axis, so the planar depth
    is the hit distance). ``normals`` / ``base``: per triangle, shared by a frame's cameras.
    Compiled per pixel; :func:`reference_rgb` is the same model in numpy."""
    opaque = raw if raw is not None else clean
    H, W = opaque.depth.shape
    face = np.ascontiguousarray(opaque.face, dtype=np.int64).reshape(-1)
    if normals is None:
        normals = face_normals(scene.mesh.vertices, scene.mesh.faces)
    rgb = shade(scene, origin, dirs, opaque.depth.reshape(-1), face, sun, up, ambient, normals, base, nthreads)
    # 4. glass in front of the opaque surface tints it; bytes
    out = np.empty((H * W, 3), dtype=np.uint8)
    tint = (np.float32(GLASS_OPACITY) * GLASS.astype(np.float32)).astype(np.float32)
    _tint_and_round(rgb, np.ascontiguousarray(clean.face, dtype=np.int64).reshape(-1), face, scene.transparent_table,
                    np.float32(1.0 - GLASS_OPACITY), tint, out)
    return out.reshape(H, W, 3)


# -- the numpy reference -----------------------------------------------------------------------------
def reference_shade(scene, origin: np.ndarray, dirs: np.ndarray, t: np.ndarray, face: np.ndarray, sun: np.ndarray,
                    up: np.ndarray, ambient: float, normals: np.ndarray, base: np.ndarray | None = None,
                    nthreads: int = 0) -> np.ndarray:
    """:func:`shade` in numpy (the reference the compiled kernels are checked against)."""
    n_rays = len(face)
    out = np.empty((n_rays, 3), dtype=np.float32)
    hit = face >= 0
    d_all = np.asarray(dirs, dtype=np.float32)
    # 1. the sky: horizon to zenith by the ray's elevation
    d = d_all[~hit]
    h = np.clip((d @ up.astype(np.float32)) / np.linalg.norm(d, axis=1), 0.0, 1.0) ** 0.6
    out[~hit] = SKY_HORIZON.astype(np.float32) + (SKY_ZENITH - SKY_HORIZON).astype(np.float32) * h[:, None]
    if not hit.any():
        return out
    if base is None:
        base = base_colours(scene.mesh.color, scene.mesh.semantic).astype(np.float32)
    f = face[hit]
    d = d_all[hit]
    # 2. the normal turned towards the camera: its sign against the ray
    n = normals[f]
    sign = np.where(np.einsum("ij,ij->i", n, d) > 0, np.float32(-1.0), np.float32(1.0))
    lambert = np.clip(sign * (n @ sun.astype(np.float32)), 0.0, 1.0)
    # 3. shadows: a ray towards the sun from each sunlit point; glass lets the light through
    lit = np.zeros(len(f), dtype=bool)
    facing = np.flatnonzero(lambert > 0)
    if facing.size:
        p = (origin + t[hit][facing, None] * d[facing]) + (SHADOW_OFFSET * sign[facing])[:, None] * n[facing]
        _, blocker = scene.cast(p, np.broadcast_to(sun, p.shape), nthreads=nthreads)
        lit[facing] = (blocker < 0) | scene.transparent(blocker)
    light = np.float32(ambient) + np.float32(1.0 - ambient) * lambert * lit
    if getattr(scene.mesh, "texture", None) is None:
        colour = base[f]
    else:  # the hits' points, where the texture is read
        colour = textured_base(scene.mesh, f, origin + t[hit][:, None].astype(np.float64) * d, base)
    out[hit] = colour * light[:, None]
    return out


def reference_rgb(scene, origin: np.ndarray, dirs: np.ndarray, clean, raw, sun: np.ndarray, up: np.ndarray,
                  ambient: float = 0.35, normals: np.ndarray | None = None, base: np.ndarray | None = None,
                  nthreads: int = 0) -> np.ndarray:
    """(H, W, 3) uint8 image of one camera from its maps: ``clean`` (first surface) and ``raw``
    (first opaque surface; None: the clean one), :class:`CameraMaps` with ``face`` set; ``origin``
    and ``dirs`` the camera's rays (unit component along the optical axis, so the planar depth
    is the hit distance). ``normals`` / ``base``: per triangle, shared by a frame's cameras.
    :func:`render_rgb` in numpy (the reference the compiled kernels are checked against)."""
    opaque = raw if raw is not None else clean
    H, W = opaque.depth.shape
    face = opaque.face.reshape(-1)
    t = opaque.depth.reshape(-1)
    if normals is None:
        normals = face_normals(scene.mesh.vertices, scene.mesh.faces)
    rgb = reference_shade(scene, origin, dirs, t, face, sun, up, ambient, normals, base, nthreads)
    # 4. glass in front of the opaque surface tints it
    front = clean.face.reshape(-1)
    glass = (front >= 0) & scene.transparent(front) & (front != face)
    rgb[glass] = (1.0 - GLASS_OPACITY) * rgb[glass] + GLASS_OPACITY * GLASS.astype(np.float32)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8).reshape(H, W, 3)
