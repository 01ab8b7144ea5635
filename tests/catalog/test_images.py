import struct
import zlib

import numpy as np
import pytest

from carlaocc.catalog.images import png_bytes, save_png


def _decode(data: bytes) -> np.ndarray:
    """A reference PNG reader for 8-bit RGB, filter 0 (what the encoder writes)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, {}
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        tag, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(tag + body) & 0xFFFFFFFF
        chunks.setdefault(tag, b"")
        chunks[tag] += body
        pos += 12 + n
    w, h, depth, colour = struct.unpack(">IIBB", chunks[b"IHDR"][:10])
    assert (depth, colour) == (8, 2)
    raw = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(h, 1 + w * 3)
    assert not raw[:, 0].any()
    return raw[:, 1:].reshape(h, w, 3)


def test_png_round_trip():
    img = np.random.default_rng(0).integers(0, 256, (17, 23, 3), dtype=np.uint8)
    data = png_bytes(img)
    np.testing.assert_array_equal(_decode(data), img)
    assert png_bytes(img) == data


def test_png_rejects_wrong_arrays():
    with pytest.raises(ValueError, match="uint8"):
        png_bytes(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError):
        png_bytes(np.zeros((4, 4), np.uint8))


def test_save_png_local_and_store(store, tmp_path):
    img = np.full((2, 3, 3), 200, np.uint8)
    save_png(None, str(tmp_path / "a.png"), img)
    np.testing.assert_array_equal(_decode((tmp_path / "a.png").read_bytes()), img)
    save_png(store, "metrics/x.png", img)
    np.testing.assert_array_equal(_decode(store.read_bytes("metrics/x.png")), img)
