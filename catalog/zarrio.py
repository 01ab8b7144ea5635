"""Chunk I/O shared by the Zarr v3 hierarchies of a store (``occupancy.zarr``, ``sensors.zarr``).

Whole chunks are encoded here (C-order little-endian bytes, zstd level :data:`ZSTD_LEVEL`: the
arrays' declared codec pipeline ``bytes`` + ``zstd``) and stored as one object each, atomically,
and decoded here too (:func:`decode_chunk`), which is about 4x faster than reading through
zarr-python. A frame of an array is named in lineage by its frame key
``<root>.zarr/<array path>[<frame>]`` and fingerprinted by its stored chunks
(:func:`frame_fingerprint`). The arrays that use this codec, their creation, tile writes and
reads, are :class:`carlaocc.catalog.zarrstore.FrameArrayStore`.
"""

from __future__ import annotations

import hashlib
import os
import tempfile

import numpy as np
from numcodecs import Zstd
from zarr.storage import FsspecStore, LocalStore

from carlaocc.catalog.store import Store

ZSTD_LEVEL = 1


def zarr_store(store: Store, name: str):
    """A zarr store object over ``<root>/<name>`` (local directory or fsspec URL)."""
    if store.is_local:
        return LocalStore(store.path(name))
    return FsspecStore.from_url(store.uri(name))


def encode_chunk(block: np.ndarray, dtype) -> bytes:
    """One whole chunk as stored: the C-order little-endian bytes of ``block`` as ``dtype``,
    zstd level :data:`ZSTD_LEVEL`. ``block`` must already have the full chunk shape."""
    little = np.dtype(dtype).newbyteorder("<")
    return Zstd(level=ZSTD_LEVEL).encode(np.ascontiguousarray(block, dtype=little))


def decode_chunk(payload: bytes, dtype, chunk_shape) -> np.ndarray:
    """The inverse of :func:`encode_chunk`: a stored chunk's array (read-only view)."""
    little = np.dtype(dtype).newbyteorder("<")
    return np.frombuffer(Zstd().decode(payload), dtype=little).reshape(chunk_shape)


def get_object(store: Store, key: str) -> bytes | None:
    """The bytes of one stored object (a chunk), or None when it is not stored (an all-zero chunk)."""
    try:
        return store.fs.cat_file(store.path(key))
    except FileNotFoundError:
        return None


def put_object(store: Store, key: str, payload: bytes) -> None:
    """Store one object (a chunk) under a store-relative key; a reader never sees half of it
    (local: a temporary ``.chunk-*`` file renamed into place)."""
    if store.is_local:
        path = store.path(key)
        directory = os.path.dirname(path)
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".chunk-")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(payload)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    else:
        store.fs.pipe_file(store.path(key), bytes(payload))


def remove_object(store: Store, key: str) -> None:
    """Remove one object (a chunk) if it is stored."""
    path = store.path(key)
    if store.is_local:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
    elif store.fs.exists(path):
        store.fs.rm_file(path)


def parse_frame_key(key: str) -> tuple[str, str, int] | None:
    """``<root>.zarr/<array path>[<frame>]`` -> (zarr root name, array path, frame); None for
    any other key (a plain file)."""
    if not (key.endswith("]") and "[" in key and "/" in key):
        return None
    root, rest = key.split("/", 1)
    if not root.endswith(".zarr"):
        return None
    path, frame = rest[:-1].rsplit("[", 1)
    if not path or not frame.isdigit():
        return None
    return root, path, int(frame)


def frame_fingerprint(store: Store, zarr_root: str, array_path: str, frame: int) -> str | None:
    """Fingerprint of one frame of an array as stored: the array metadata (``zarr.json``), then
    the names and encoded bytes of its chunk files under ``<array>/c/<frame>`` (all-empty chunks
    are not stored; dot-prefixed temporary files are skipped). Cheap (compressed bytes) and
    sensitive to a deleted, truncated or rewritten chunk; None when the array does not exist."""
    fs, base = store.fs, store.path(f"{zarr_root}/{array_path}")
    try:
        meta = fs.cat_file(f"{base}/zarr.json")
    except FileNotFoundError:
        return None
    h = hashlib.sha256(meta)
    prefix = f"{base}/c/{frame}"
    files = sorted(fs.find(prefix)) if fs.exists(prefix) else []
    for f in files:
        if f.rsplit("/", 1)[-1].startswith("."):
            continue  # a temporary chunk left by a crashed write is not part of the frame
        h.update(f[len(prefix):].encode())
        h.update(fs.cat_file(f))
    return "sha256:" + h.hexdigest()[:24]
