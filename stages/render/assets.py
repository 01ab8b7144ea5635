"""Headless asset previews: RGB images of mesh parts, drawn with the shared rasterizer of
:mod:`carlaocc.stages.render.raster` (no GUI, no OpenGL, no imaging library).

Camera and shading (:func:`render_asset`):

* **Orthographic** camera looking at the centre of the parts' axis-aligned bounding box from
  ``azimuth_deg`` (about +Z, from +X towards +Y) and ``elevation_deg`` (above the horizon). The
  defaults (-35, 25) look at the front-right of an asset in the asset frame (+X forward, Z up).
  The projected bounding box is fitted into the image with a margin, keeping the aspect ratio.
* **Flat Lambert** shading per triangle with the part's RGB colour: ``ambient + diffuse *
  max(0, n . l)``, with a key light fixed relative to the camera (from the upper left, in front).
  Triangles are two-sided (the normal is turned towards the camera), so open or inconsistently
  wound meshes render too.
* **Transparent parts** (``MeshPart.transparent``) are drawn after every opaque part, back to
  front (by triangle centroid depth), blended over what is behind them with the part colour's
  alpha (``color[3] / 255``, at least 0.15, at most 0.85), depth-tested against the opaque
  surfaces but not writing depth: glass reads as a tinted see-through surface.
* An optional **ground shadow**: the opaque triangles projected along the key light onto the
  plane under the asset (its lowest z), drawn as a darkened background.
* ``antialias`` supersampling (render at ``antialias`` times the size, then average blocks).

Everything is deterministic: the same parts and arguments give byte-identical images.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.render.raster import AMBIENT, DIFFUSE, camera_axes, image_size, key_light, raster_triangles

__all__ = ["asset_sheet", "render_asset"]

SHADOW_DARKEN = 0.80  # the ground shadow multiplies the background by this


def render_asset(
    parts: Sequence[MeshPart],
    size=(512, 512),
    elevation_deg: float = 25.0,
    azimuth_deg: float = -35.0,
    background=(255, 255, 255),
    *,
    shadow: bool = True,
    antialias: int = 2,
    margin: float = 0.06,
) -> np.ndarray:
    """Render mesh parts (vertices in metres, any frame with Z up) to an RGB image.

    ``size`` is ``(height, width)`` in pixels (or one int for a square); the result is a
    ``(height, width, 3)`` uint8 array. The orthographic camera frames the parts' bounding box
    (``margin`` of the image on each side) from ``azimuth_deg``/``elevation_deg``; opaque parts are
    Lambert-shaded with their colour, transparent parts blended over them (see the module
    docstring), and ``shadow`` adds the opaque parts' shadow on the ground plane under them
    (only when looking from above). Parts without triangles are skipped; with none at all the
    image is the background."""
    H, W = image_size(size)
    ss = max(1, int(antialias))
    bg = np.asarray(background, dtype=np.float64).reshape(3)
    Hs, Ws = H * ss, W * ss
    img = np.empty((Hs, Ws, 3), dtype=np.float64)
    img[:] = bg
    zbuf = np.full((Hs, Ws), np.inf)
    parts = [p for p in parts if len(p.faces) and len(p.vertices)]
    if not parts:
        return np.ascontiguousarray(np.round(bg).astype(np.uint8)[None, None, :].repeat(H, 0).repeat(W, 1))

    # one mesh: vertices, faces, per-face colour / alpha / transparency
    verts, faces, rgb, alpha, glass = [], [], [], [], []
    offset = 0
    for p in parts:
        verts.append(np.asarray(p.vertices, dtype=np.float64))
        faces.append(np.asarray(p.faces, dtype=np.int64) + offset)
        offset += len(p.vertices)
        n = len(p.faces)
        rgb.append(np.tile(np.asarray(p.color[:3], dtype=np.float64), (n, 1)))
        a = p.color[3] / 255.0 if len(p.color) > 3 else 1.0
        alpha.append(np.full(n, min(max(a, 0.15), 0.85) if p.transparent else 1.0))
        glass.append(np.full(n, bool(p.transparent)))
    V, F = np.concatenate(verts), np.concatenate(faces)
    rgb, alpha, glass = np.concatenate(rgb), np.concatenate(alpha), np.concatenate(glass)

    # camera, framing: fit the projected bounding box of the parts into the image
    right, up, fwd = camera_axes(elevation_deg, azimuth_deg)
    lo, hi = V.min(axis=0), V.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cu, cv = corners @ right, corners @ up
    span_u, span_v = max(cu.max() - cu.min(), 1e-9), max(cv.max() - cv.min(), 1e-9)
    usable = 1.0 - 2.0 * min(max(margin, 0.0), 0.45)
    scale = min(Ws * usable / span_u, Hs * usable / span_v)
    uc, vc = (cu.max() + cu.min()) / 2, (cv.max() + cv.min()) / 2

    def project(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = Ws / 2 + (P @ right - uc) * scale
        y = Hs / 2 - (P @ up - vc) * scale
        return np.ascontiguousarray(x), np.ascontiguousarray(y), np.ascontiguousarray(P @ fwd)

    px, py, pz = project(V)

    light = key_light(right, up, fwd)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    normal = normal / np.where(length > 0, length, 1.0)[:, None]
    normal *= np.where(normal @ fwd > 0, -1.0, 1.0)[:, None]  # two-sided: face the camera
    shade = AMBIENT + DIFFUSE * np.clip(normal @ light, 0.0, 1.0)
    colours = np.clip(rgb * shade[:, None], 0.0, 255.0)

    opaque = np.flatnonzero(~glass)
    if shadow and light[2] > 0.05 and elevation_deg > 0 and opaque.size:
        # project the opaque triangles along the light onto the ground plane z = lo[2]
        S = V - np.outer((V[:, 2] - lo[2]) / light[2], light)
        sx, sy, sz = project(S)
        shadow_rgb = np.tile(bg * SHADOW_DARKEN, (opaque.size, 1))
        raster_triangles(sx, sy, sz + 1e-6, np.ascontiguousarray(F[opaque]), shadow_rgb, np.ones(opaque.size),
                         False, zbuf, img)  # fmt: skip
    if opaque.size:
        raster_triangles(px, py, pz, np.ascontiguousarray(F[opaque]), np.ascontiguousarray(colours[opaque]),
                         np.ones(opaque.size), False, zbuf, img)  # fmt: skip
    clear = np.flatnonzero(glass)
    if clear.size:
        depth = pz[F[clear]].mean(axis=1)
        clear = clear[np.argsort(-depth, kind="stable")]  # back to front
        raster_triangles(px, py, pz, np.ascontiguousarray(F[clear]), np.ascontiguousarray(colours[clear]),
                         np.ascontiguousarray(alpha[clear]), True, zbuf, img)  # fmt: skip

    if ss > 1:  # box filter down to the requested size
        img = img.reshape(H, ss, W, ss, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(np.clip(np.round(img), 0, 255).astype(np.uint8))


def asset_sheet(images: Sequence[np.ndarray], labels: Sequence[str], class_ids, columns: int = 6,
                translucent: bool = False, title: str | None = None):
    """A sheet of asset previews (:func:`render_asset`, parts in their class colours): rows of
    ``columns`` panels titled with ``labels``, the first row's key naming the classes
    ``class_ids`` drawn (their palette swatches) and, with ``translucent``, that glass is drawn
    see-through. Returns a :class:`carlaocc.stages.render.layout.Sheet`."""
    from carlaocc.schemas.taxonomy import CLASSES, palette
    from carlaocc.stages.render.layout import Key, LegendEntry, Panel, compose

    if len(images) != len(labels):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    if not images or columns < 1:
        raise ValueError("asset_sheet needs at least one image and one column")
    panels = [Panel(str(lab), np.asarray(im, np.uint8)[:, :, :3]) for im, lab in zip(images, labels)]
    entries = [LegendEntry(CLASSES[c].name, (tuple(palette()[c]),)) for c in sorted(set(int(c) for c in class_ids))
               if 0 <= c < len(CLASSES)]
    if translucent:
        entries.append(LegendEntry("translucent: glass (drawn see-through)", kind="text"))
    key = Key("colour: class of each part", tuple(entries))
    rows = [(panels[k : k + columns], key if k == 0 else None) for k in range(0, len(panels), columns)]
    return compose(rows, title=title)
