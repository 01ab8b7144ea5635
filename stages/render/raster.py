"""The one triangle rasterizer every renderer draws with, and the camera and light they share.

* :func:`fill_triangle` -- a numba kernel drawing one screen triangle into a z-buffer and an RGB
  float image: it loops over the triangle's pixel bounding box, tests each pixel centre with edge
  functions (either winding) and interpolates depth barycentrically. Opaque fragments nearer
  than the stored depth replace colour and depth; in blend mode they are alpha-blended over the
  colour without writing depth; an optional border darkens the pixels near the edges of the
  quad the triangle belongs to (voxel faces).
* :func:`raster_triangles` -- a triangle list with one colour and alpha per triangle, through
  :func:`fill_triangle` (the asset previews).
* :func:`camera_axes`, :func:`key_light`, :data:`AMBIENT`, :data:`DIFFUSE` -- the view direction
  from an azimuth and an elevation, and the flat Lambert lighting of every view;
  :func:`image_size` reads a ``size`` argument.

Screen coordinates are pixels with y down, the pixel ``(row, col)`` covering ``[col, col + 1) x
[row, row + 1)``; depth is any quantity growing away from the camera (larger = farther).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "AMBIENT",
    "DIFFUSE",
    "barycentric",
    "camera_axes",
    "fill_triangle",
    "image_size",
    "key_light",
    "raster_triangles",
    "tri_pixel_box",
]

AMBIENT = 0.38  # share of the colour a triangle keeps when facing away from the light
DIFFUSE = 0.62  # share added by a triangle facing the light


@njit(cache=True, nogil=True, inline="always")
def tri_pixel_box(x0, y0, x1, y1, x2, y2, W, H):  # pragma: no cover - numba
    """(1 / signed area, xmin, xmax, ymin, ymax) of a screen triangle (pixels), its pixel box
    clipped to a W x H image; 1 / area is 0.0 for a degenerate triangle."""
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if abs(area) < 1e-12:
        return 0.0, 0, -1, 0, -1
    xmin = max(int(math.floor(min(x0, min(x1, x2)))), 0)
    xmax = min(int(math.ceil(max(x0, max(x1, x2)))), W - 1)
    ymin = max(int(math.floor(min(y0, min(y1, y2)))), 0)
    ymax = min(int(math.ceil(max(y0, max(y1, y2)))), H - 1)
    return 1.0 / area, xmin, xmax, ymin, ymax


@njit(cache=True, nogil=True, inline="always")
def barycentric(x0, y0, x1, y1, x2, y2, cx, cy, inv):  # pragma: no cover - numba
    """Barycentric weights of the pixel point (cx, cy) from signed areas times ``inv`` =
    1 / area (normalized, so either winding works)."""
    w0 = ((x1 - cx) * (y2 - cy) - (x2 - cx) * (y1 - cy)) * inv
    w1 = ((x2 - cx) * (y0 - cy) - (x0 - cx) * (y2 - cy)) * inv
    return w0, w1, 1.0 - w0 - w1


@njit(cache=True, nogil=True)
def fill_triangle(x0, y0, z0, s0, t0, x1, y1, z1, s1, t1, x2, y2, z2, s2, t2, r, g, b, alpha, blend,
                  ls, lt, edge, dark, zbuf, img):  # pragma: no cover - numba  # fmt: skip
    """Draw one triangle with screen vertices (x, y) in pixels and depths z into ``zbuf`` (H, W)
    and ``img`` (H, W, 3) float. A pixel is covered when its centre lies inside the triangle
    (either winding) and its interpolated depth is nearer than ``zbuf``.

    Opaque (``blend`` False): the fragment writes its depth and the colour (r, g, b). Blend: the
    colour is blended over the image with ``alpha``, ``img * (1 - alpha) + colour * alpha``, and
    the depth is not written. Border: (s, t) are the vertices' coordinates in the quad the triangle
    belongs to (0..1 along its sides, ``ls`` and ``lt`` pixels long); pixels within ``edge``
    pixels of the quad's border take the colour times ``dark`` (``edge`` 0: no border)."""
    H, W = zbuf.shape
    inv, xmin, xmax, ymin, ymax = tri_pixel_box(x0, y0, x1, y1, x2, y2, W, H)
    if inv == 0.0:
        return  # degenerate on screen
    for yy in range(ymin, ymax + 1):
        cy = yy + 0.5
        for xx in range(xmin, xmax + 1):
            w0, w1, w2 = barycentric(x0, y0, x1, y1, x2, y2, xx + 0.5, cy, inv)
            if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                continue
            z = w0 * z0 + w1 * z1 + w2 * z2
            if z >= zbuf[yy, xx]:
                continue
            k = 1.0
            if edge > 0.0:
                s = w0 * s0 + w1 * s1 + w2 * s2
                t = w0 * t0 + w1 * t1 + w2 * t2
                d = min(min(s, 1.0 - s) * ls, min(t, 1.0 - t) * lt)
                if d < edge:
                    k = dark
            if blend:
                img[yy, xx, 0] = img[yy, xx, 0] * (1.0 - alpha) + r * k * alpha
                img[yy, xx, 1] = img[yy, xx, 1] * (1.0 - alpha) + g * k * alpha
                img[yy, xx, 2] = img[yy, xx, 2] * (1.0 - alpha) + b * k * alpha
            else:
                zbuf[yy, xx] = z
                img[yy, xx, 0] = r * k
                img[yy, xx, 1] = g * k
                img[yy, xx, 2] = b * k


@njit(cache=True)
def raster_triangles(px, py, pz, tris, cols, alpha, blend, zbuf, img):  # pragma: no cover - numba
    """Rasterize triangles ``tris`` (M, 3) with screen vertices ``px``, ``py`` (pixels, y down)
    and depth ``pz`` into ``zbuf`` and ``img`` with :func:`fill_triangle`, in list order, each in
    its colour ``cols[t]`` (RGB 0..255) and, in ``blend`` mode, its ``alpha[t]``."""
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        fill_triangle(px[i0], py[i0], pz[i0], 0.0, 0.0, px[i1], py[i1], pz[i1], 0.0, 0.0,
                      px[i2], py[i2], pz[i2], 0.0, 0.0, cols[t, 0], cols[t, 1], cols[t, 2], alpha[t], blend,
                      0.0, 0.0, 0.0, 1.0, zbuf, img)  # fmt: skip


def image_size(size) -> tuple[int, int]:
    """``(height, width)`` in pixels from an int or a pair; ``ValueError`` unless both are >= 1."""
    h, w = (size, size) if isinstance(size, (int, np.integer)) else size
    h, w = int(h), int(w)
    if h < 1 or w < 1:
        raise ValueError(f"image size must be positive, got {size!r}")
    return h, w


def camera_axes(elevation_deg: float, azimuth_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of a camera looking from ``azimuth_deg`` (about +Z, from
    +X towards +Y) and ``elevation_deg`` (above the horizon), Z up: ``forward`` points from the
    camera into the scene; screen x is ``right`` (horizontal, so the horizon stays level), screen
    y (upwards) is ``up``."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    to_camera = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    forward = -to_camera
    right = np.array([-math.sin(az), math.cos(az), 0.0])
    up = np.cross(right, forward)
    return right, up / np.linalg.norm(up), forward


def key_light(right: np.ndarray, up: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Unit direction towards the key light, fixed to the camera: from the upper left, in front.
    A surface with unit normal n is shaded ``AMBIENT + DIFFUSE * max(0, n . light)``."""
    light = -0.40 * right + 0.55 * up - 0.75 * forward
    light /= np.linalg.norm(light)
    return light
