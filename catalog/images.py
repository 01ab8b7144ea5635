"""PNG images: a minimal, dependency-free encoder (zlib + CRC chunks) of 8-bit RGB and 16-bit
grey images, written atomically."""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np

from carlaocc.catalog.store import Store


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an (H, W, 3) uint8 RGB image (8-bit truecolour) or an (H, W) uint16 image (16-bit
    greyscale, e.g. depth) as PNG (filter 0, deterministic)."""
    img = np.ascontiguousarray(image)
    if img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8:
        h, w, _ = img.shape
        rows, depth, colour = img.reshape(h, w * 3), 8, 2
    elif img.ndim == 2 and img.dtype == np.uint16:
        h, w = img.shape
        # PNG samples are big-endian
        rows, depth, colour = img.astype(">u2").view(np.uint8).reshape(h, w * 2), 16, 0
    else:
        raise ValueError(f"expected an (H, W, 3) uint8 or an (H, W) uint16 image, got {img.shape} {img.dtype}")
    # each scanline prefixed with filter type 0 (none)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")


def save_png(store: Store | None, path: str, image: np.ndarray) -> str:
    """Write a PNG into the store (store-relative path) or, with ``store=None``, to a local path."""
    data = png_bytes(image)
    if store is None:
        target = Store(os.path.dirname(os.path.abspath(path)) or ".")
        return target.write_bytes(os.path.basename(path), data)
    return store.write_bytes(path, data)
