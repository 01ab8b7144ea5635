"""The built-in 5x7 bitmap font and labelled contact sheets, for every picture that needs words.

:func:`draw_text` draws a string into an RGB image (each font pixel a ``scale`` x ``scale``
block, characters 6 font pixels apart, clipped at the image border); :func:`text_width` and
:func:`label_strip_height` size it; :func:`contact_sheet` tiles images into a grid with a label
strip under each one. Pure numpy, deterministic.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "FONT_HEIGHT",
    "FONT_WIDTH",
    "contact_sheet",
    "draw_text",
    "label_strip_height",
    "text_width",
]

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
