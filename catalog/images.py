"""PNG images: a minimal, dependency-free RGB8 encoder (zlib + CRC chunks), written atomically."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from carlaocc.catalog.store import Store


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an (H, W, 3) uint8 RGB image as PNG (8-bit truecolour, filter 0, deterministic)."""
    img = np.ascontiguousarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
    h, w, _ = img.shape
    # each scanline prefixed with filter type 0 (none)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), img.reshape(h, w * 3)], axis=1).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")


def save_png(store: Store | None, path: str, image: np.ndarray) -> str:
    """Write a PNG into the store (store-relative path) or, with ``store=None``, to a local path."""
    data = png_bytes(image)
    if store is None:
        import os

        target = Store(os.path.dirname(os.path.abspath(path)) or ".")
        return target.write_bytes(os.path.basename(path), data)
    return store.write_bytes(path, data)
