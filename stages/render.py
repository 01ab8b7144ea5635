"""Headless preview rendering: RGB images of mesh parts and labelled contact sheets, pure numpy.

No GUI, no OpenGL, no imaging library: a z-buffer triangle rasterizer (a numba kernel looping over
each triangle's pixel bounding box with edge functions) and a tiny built-in 5x7 bitmap font.

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

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from carlaocc.stages.geometry import MeshPart

__all__ = [
    "FONT_HEIGHT",
    "FONT_WIDTH",
    "contact_sheet",
    "draw_text",
    "label_strip_height",
    "render_asset",
    "text_width",
]

AMBIENT = 0.38  # share of the colour a triangle keeps when facing away from the light
DIFFUSE = 0.62  # share added by a triangle facing the light
SHADOW_DARKEN = 0.80  # the ground shadow multiplies the background by this


# --------------------------------------------------------------------------------------------
# rasterizer
# --------------------------------------------------------------------------------------------


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


@njit(cache=True)
def _raster(px, py, pz, tris, cols, alpha, blend, zbuf, img):  # pragma: no cover - numba
    """Rasterize triangles ``tris`` (M, 3) with screen vertices ``px``, ``py`` (pixels, y down)
    and depth ``pz`` (larger = farther) into ``zbuf`` (H, W) and ``img`` (H, W, 3) float64.
    A pixel is covered when its centre lies inside the triangle (either winding). Opaque mode
    (``blend`` False): nearer fragments replace colour and depth. Blend mode: fragments in front
    of the stored depth are alpha-blended over the colour; depth is not written."""
    H, W = zbuf.shape
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        x0, y0, z0 = px[i0], py[i0], pz[i0]
        x1, y1, z1 = px[i1], py[i1], pz[i1]
        x2, y2, z2 = px[i2], py[i2], pz[i2]
        inv, xmin, xmax, ymin, ymax = tri_pixel_box(x0, y0, x1, y1, x2, y2, W, H)
        if inv == 0.0:
            continue  # degenerate on screen
        r, g, b, a = cols[t, 0], cols[t, 1], cols[t, 2], alpha[t]
        for yy in range(ymin, ymax + 1):
            cy = yy + 0.5
            for xx in range(xmin, xmax + 1):
                w0, w1, w2 = barycentric(x0, y0, x1, y1, x2, y2, xx + 0.5, cy, inv)
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z >= zbuf[yy, xx]:
                    continue
                if blend:
                    img[yy, xx, 0] = img[yy, xx, 0] * (1.0 - a) + r * a
                    img[yy, xx, 1] = img[yy, xx, 1] * (1.0 - a) + g * a
                    img[yy, xx, 2] = img[yy, xx, 2] * (1.0 - a) + b * a
                else:
                    zbuf[yy, xx] = z
                    img[yy, xx, 0] = r
                    img[yy, xx, 1] = g
                    img[yy, xx, 2] = b


def _size(size) -> tuple[int, int]:
    """``(height, width)`` in pixels from an int or a pair."""
    h, w = (size, size) if isinstance(size, (int, np.integer)) else size
    h, w = int(h), int(w)
    if h < 1 or w < 1:
        raise ValueError(f"image size must be positive, got {size!r}")
    return h, w


def _camera(elevation_deg: float, azimuth_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of the camera: ``forward`` points from the camera into
    the scene; screen x is ``right``, screen y (upwards) is ``up``."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    to_camera = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    forward = -to_camera
    right = np.array([-math.sin(az), math.cos(az), 0.0])  # horizontal, so the horizon stays level
    up = np.cross(right, forward)
    return right, up / np.linalg.norm(up), forward


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
    H, W = _size(size)
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
    right, up, fwd = _camera(elevation_deg, azimuth_deg)
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

    # key light fixed to the camera: from the upper left, in front
    light = -0.40 * right + 0.55 * up - 0.75 * fwd
    light /= np.linalg.norm(light)
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
        _raster(sx, sy, sz + 1e-6, np.ascontiguousarray(F[opaque]), shadow_rgb, np.ones(opaque.size), False, zbuf, img)
    if opaque.size:
        _raster(px, py, pz, np.ascontiguousarray(F[opaque]), np.ascontiguousarray(colours[opaque]),
                np.ones(opaque.size), False, zbuf, img)  # fmt: skip
    clear = np.flatnonzero(glass)
    if clear.size:
        depth = pz[F[clear]].mean(axis=1)
        clear = clear[np.argsort(-depth, kind="stable")]  # back to front
        _raster(px, py, pz, np.ascontiguousarray(F[clear]), np.ascontiguousarray(colours[clear]),
                np.ascontiguousarray(alpha[clear]), True, zbuf, img)  # fmt: skip

    if ss > 1:  # box filter down to the requested size
        img = img.reshape(H, ss, W, ss, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(np.clip(np.round(img), 0, 255).astype(np.uint8))


# --------------------------------------------------------------------------------------------
# a tiny 5x7 bitmap font and labelled contact sheets
# --------------------------------------------------------------------------------------------

FONT_WIDTH, FONT_HEIGHT = 5, 7  # glyph cell in font pixels; characters advance by 6

# one glyph per line: seven rows of five pixels ("#" set), rows separated by "|"
_FONT_ROWS: dict[str, str] = {
    "A": ".###.|#...#|#...#|#####|#...#|#...#|#...#", "B": "####.|#...#|#...#|####.|#...#|#...#|####.",
    "C": ".###.|#...#|#....|#....|#....|#...#|.###.", "D": "###..|#..#.|#...#|#...#|#...#|#..#.|###..",
    "E": "#####|#....|#....|####.|#....|#....|#####", "F": "#####|#....|#....|####.|#....|#....|#....",
    "G": ".###.|#...#|#....|#.###|#...#|#...#|.####", "H": "#...#|#...#|#...#|#####|#...#|#...#|#...#",
    "I": ".###.|..#..|..#..|..#..|..#..|..#..|.###.", "J": "..###|...#.|...#.|...#.|...#.|#..#.|.##..",
    "K": "#...#|#..#.|#.#..|##...|#.#..|#..#.|#...#", "L": "#....|#....|#....|#....|#....|#....|#####",
    "M": "#...#|##.##|#.#.#|#.#.#|#...#|#...#|#...#", "N": "#...#|#...#|##..#|#.#.#|#..##|#...#|#...#",
    "O": ".###.|#...#|#...#|#...#|#...#|#...#|.###.", "P": "####.|#...#|#...#|####.|#....|#....|#....",
    "Q": ".###.|#...#|#...#|#...#|#.#.#|#..#.|.##.#", "R": "####.|#...#|#...#|####.|#.#..|#..#.|#...#",
    "S": ".####|#....|#....|.###.|....#|....#|####.", "T": "#####|..#..|..#..|..#..|..#..|..#..|..#..",
    "U": "#...#|#...#|#...#|#...#|#...#|#...#|.###.", "V": "#...#|#...#|#...#|#...#|#...#|.#.#.|..#..",
    "W": "#...#|#...#|#...#|#.#.#|#.#.#|#.#.#|.#.#.", "X": "#...#|#...#|.#.#.|..#..|.#.#.|#...#|#...#",
    "Y": "#...#|#...#|.#.#.|..#..|..#..|..#..|..#..", "Z": "#####|....#|...#.|..#..|.#...|#....|#####",
    "a": ".....|.....|.###.|....#|.####|#...#|.####", "b": "#....|#....|#.##.|##..#|#...#|#...#|####.",
    "c": ".....|.....|.###.|#....|#....|#...#|.###.", "d": "....#|....#|.##.#|#..##|#...#|#...#|.####",
    "e": ".....|.....|.###.|#...#|#####|#....|.###.", "f": "..##.|.#..#|.#...|###..|.#...|.#...|.#...",
    "g": ".....|.....|.####|#...#|.####|....#|.###.", "h": "#....|#....|#.##.|##..#|#...#|#...#|#...#",
    "i": "..#..|.....|.##..|..#..|..#..|..#..|.###.", "j": "...#.|.....|..##.|...#.|...#.|#..#.|.##..",
    "k": "#....|#....|#..#.|#.#..|##...|#.#..|#..#.", "l": ".##..|..#..|..#..|..#..|..#..|..#..|.###.",
    "m": ".....|.....|##.#.|#.#.#|#.#.#|#...#|#...#", "n": ".....|.....|#.##.|##..#|#...#|#...#|#...#",
    "o": ".....|.....|.###.|#...#|#...#|#...#|.###.", "p": ".....|.....|####.|#...#|####.|#....|#....",
    "q": ".....|.....|.####|#...#|.####|....#|....#", "r": ".....|.....|#.##.|##..#|#....|#....|#....",
    "s": ".....|.....|.####|#....|.###.|....#|####.", "t": ".#...|.#...|###..|.#...|.#...|.#..#|..##.",
    "u": ".....|.....|#...#|#...#|#...#|#..##|.##.#", "v": ".....|.....|#...#|#...#|#...#|.#.#.|..#..",
    "w": ".....|.....|#...#|#...#|#.#.#|#.#.#|.#.#.", "x": ".....|.....|#...#|.#.#.|..#..|.#.#.|#...#",
    "y": ".....|.....|#...#|#...#|.####|....#|.###.", "z": ".....|.....|#####|...#.|..#..|.#...|#####",
    "0": ".###.|#...#|#..##|#.#.#|##..#|#...#|.###.", "1": "..#..|.##..|..#..|..#..|..#..|..#..|.###.",
    "2": ".###.|#...#|....#|...#.|..#..|.#...|#####", "3": "#####|...#.|..#..|...#.|....#|#...#|.###.",
    "4": "...#.|..##.|.#.#.|#..#.|#####|...#.|...#.", "5": "#####|#....|####.|....#|....#|#...#|.###.",
    "6": "..##.|.#...|#....|####.|#...#|#...#|.###.", "7": "#####|....#|...#.|..#..|.#...|.#...|.#...",
    "8": ".###.|#...#|#...#|.###.|#...#|#...#|.###.", "9": ".###.|#...#|#...#|.####|....#|...#.|.##..",
    " ": ".....|.....|.....|.....|.....|.....|.....", ".": ".....|.....|.....|.....|.....|.##..|.##..",
    ",": ".....|.....|.....|.....|.##..|..#..|.#...", ":": ".....|.##..|.##..|.....|.##..|.##..|.....",
    ";": ".....|.##..|.##..|.....|.##..|..#..|.#...", "-": ".....|.....|.....|#####|.....|.....|.....",
    "_": ".....|.....|.....|.....|.....|.....|#####", "/": ".....|....#|...#.|..#..|.#...|#....|.....",
    "(": "...#.|..#..|.#...|.#...|.#...|..#..|...#.", ")": ".#...|..#..|...#.|...#.|...#.|..#..|.#...",
    "[": ".###.|.#...|.#...|.#...|.#...|.#...|.###.", "]": ".###.|...#.|...#.|...#.|...#.|...#.|.###.",
    "#": ".#.#.|.#.#.|#####|.#.#.|#####|.#.#.|.#.#.", "+": ".....|..#..|..#..|#####|..#..|..#..|.....",
    "=": ".....|.....|#####|.....|#####|.....|.....", "%": "##...|##..#|...#.|..#..|.#...|#..##|...##",
    "!": "..#..|..#..|..#..|..#..|..#..|.....|..#..", "?": ".###.|#...#|....#|...#.|..#..|.....|..#..",
    "'": "..#..|..#..|.#...|.....|.....|.....|.....", "*": ".....|..#..|#.#.#|.###.|#.#.#|..#..|.....",
    "<": "...#.|..#..|.#...|#....|.#...|..#..|...#.", ">": ".#...|..#..|...#.|....#|...#.|..#..|.#...",
    "|": "..#..|..#..|..#..|..#..|..#..|..#..|..#..", "~": ".....|.....|.#...|#.#.#|...#.|.....|.....",
}  # fmt: skip


def _glyph_table() -> dict[str, np.ndarray]:
    """Boolean (7, 5) bitmaps of :data:`_FONT_ROWS` (checked at import)."""
    out = {}
    for ch, spec in _FONT_ROWS.items():
        rows = spec.split("|")
        if len(rows) != FONT_HEIGHT or any(len(r) != FONT_WIDTH for r in rows):
            raise RuntimeError(f"bad glyph {ch!r}")
        out[ch] = np.array([[c == "#" for c in r] for r in rows], dtype=bool)
    return out


_GLYPHS = _glyph_table()


def text_width(text: str, scale: int = 1) -> int:
    """Width in pixels of ``text`` drawn by :func:`draw_text` (6 pixels a character, less the
    trailing gap)."""
    return max(0, len(text) * (FONT_WIDTH + 1) - 1) * int(scale)


def draw_text(img: np.ndarray, text: str, x: int, y: int, color=(0, 0, 0), scale: int = 1) -> np.ndarray:
    """Draw ``text`` into ``img`` (H, W, 3) in place with the built-in 5x7 font, its top-left
    corner at pixel column ``x``, row ``y``, each font pixel a ``scale`` x ``scale`` block.
    Characters without a glyph are drawn as ``?``; pixels outside the image are clipped.
    Returns ``img``."""
    s = int(scale)
    if s < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    colour = np.asarray(color, dtype=img.dtype)
    H, W = img.shape[:2]
    for k, ch in enumerate(text):
        glyph = _GLYPHS.get(ch, _GLYPHS["?"])
        big = np.repeat(np.repeat(glyph, s, axis=0), s, axis=1)
        x0, y0 = x + k * (FONT_WIDTH + 1) * s, y
        # clip the glyph block to the image
        gx0, gy0 = max(0, -x0), max(0, -y0)
        gx1, gy1 = min(big.shape[1], W - x0), min(big.shape[0], H - y0)
        if gx1 <= gx0 or gy1 <= gy0:
            continue
        mask = big[gy0:gy1, gx0:gx1]
        img[y0 + gy0 : y0 + gy1, x0 + gx0 : x0 + gx1][mask] = colour
    return img


def label_strip_height(scale: int) -> int:
    """Height in pixels of the label strip under each contact-sheet cell at font ``scale``."""
    return (FONT_HEIGHT + 4) * int(scale)


def contact_sheet(
    images: Sequence[np.ndarray],
    labels: Sequence[str],
    columns: int = 6,
    *,
    label_scale: int | None = None,
    background=(255, 255, 255),
    label_background=(236, 236, 236),
    text_color=(20, 20, 20),
) -> np.ndarray:
    """Tile images into a grid with a label strip under each one.

    Every cell is as large as the largest image (smaller images are centred on ``background``)
    plus a strip of :func:`label_strip_height` pixels holding the label, centred, in the built-in
    font (truncated with ``..`` when too long for the cell). ``min(columns, len(images))``
    columns, as many rows as needed; empty trailing cells are background. The result is
    ``(rows * (cell_h + strip), cols * cell_w, 3)`` uint8. ``label_scale`` defaults to 1 for
    cells narrower than 256 px, else ``cell_w // 256 + 1`` (at most 3). Grey (H, W) images are
    accepted; other dtypes are clipped to 0..255."""
    if len(images) != len(labels):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    if not images:
        raise ValueError("contact_sheet needs at least one image")
    if columns < 1:
        raise ValueError(f"columns must be >= 1, got {columns}")
    tiles = []
    for im in images:
        a = np.asarray(im)
        if a.ndim == 2:
            a = np.repeat(a[:, :, None], 3, axis=2)
        if a.ndim != 3 or a.shape[2] not in (3, 4):
            raise ValueError(f"images must be (H, W), (H, W, 3) or (H, W, 4), got {a.shape}")
        tiles.append(np.clip(a[:, :, :3], 0, 255).astype(np.uint8))
    cell_h = max(t.shape[0] for t in tiles)
    cell_w = max(t.shape[1] for t in tiles)
    scale = int(label_scale) if label_scale is not None else min(3, 1 if cell_w < 256 else cell_w // 256 + 1)
    strip = label_strip_height(scale)
    cols = min(columns, len(tiles))
    rows = -(-len(tiles) // cols)
    sheet = np.empty((rows * (cell_h + strip), cols * cell_w, 3), dtype=np.uint8)
    sheet[:] = np.asarray(background, dtype=np.uint8)
    max_chars = max(1, (cell_w - 2 * scale + scale) // ((FONT_WIDTH + 1) * scale))
    for k, (tile, label) in enumerate(zip(tiles, labels)):
        r, c = divmod(k, cols)
        y0, x0 = r * (cell_h + strip), c * cell_w
        th, tw = tile.shape[:2]
        oy, ox = y0 + (cell_h - th) // 2, x0 + (cell_w - tw) // 2
        sheet[oy : oy + th, ox : ox + tw] = tile
        sheet[y0 + cell_h : y0 + cell_h + strip, x0 : x0 + cell_w] = np.asarray(label_background, dtype=np.uint8)
        text = str(label)
        if len(text) > max_chars:
            text = text[: max(0, max_chars - 2)] + ".."[: max_chars]
        tx = x0 + (cell_w - text_width(text, scale)) // 2
        draw_text(sheet, text, tx, y0 + cell_h + 2 * scale, text_color, scale)
    return sheet
