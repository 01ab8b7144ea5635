"""Chunk I/O shared by the Zarr v3 hierarchies of a store (``occupancy.zarr``, ``sensors.zarr``).

Whole chunks are encoded here (C-order little-endian bytes, zstd level :data:`ZSTD_LEVEL`: the
arrays' declared codec pipeline ``bytes`` + ``zstd``) and stored as one object each, atomically,
and decoded here too (:func:`decode_chunk`), which is about 4x faster than reading through
zarr-python. A frame of an array is named in lineage by its frame key
``<root>.zarr/<array path>[<frame>]`` and fingerprinted by its stored chunks
(:func:`frame_fingerprint`). The arrays that use this codec, their creation, tile writes and
reads, are :class:`carlaocc.catalog.zarrstore.FrameArrayStore`.

Damage (a truncated or overwritten ``zarr.json`` of an array or of a group above it, a chunk that
is not a whole zstd frame of the chunk's size) is never an exception here: :func:`metadata_problem`
says what is wrong with a node's metadata and :func:`frame_fingerprint` gives a frame with an
unreadable part the fingerprint ``damaged: <path> unreadable`` (:func:`is_damaged`), which matches
no recorded fingerprint, so the frame is stale and a re-run rebuilds it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import uuid

import numpy as np
from numcodecs import Zstd
from zarr.storage import FsspecStore, LocalStore

from carlaocc.catalog.store import Store

ZSTD_LEVEL = 1


def zarr_store(store: Store, name: str):
    """A zarr store object over ``<root>/<name>`` (local directory or fsspec URL)."""
    if store.is_local:
        return LocalStore(store.path(name))
    return FsspecStore.from_url(store.uri(name), storage_options=store.storage_options or None)


def encode_chunk(block: np.ndarray, dtype, level: int = ZSTD_LEVEL) -> bytes:
    """One whole chunk as stored: the C-order little-endian bytes of ``block`` as ``dtype``,
    zstd ``level`` (:data:`ZSTD_LEVEL` by default; any level decodes the same way). ``block``
    must already have the full chunk shape. A block that is not C-contiguous little-endian
    ``dtype`` (a chunk sliced out of a tile) is copied into this thread's reused buffer first:
    fresh pages for every 4-16 MB chunk cost about three times the copy itself."""
    little = np.dtype(dtype).newbyteorder("<")
    block = np.asarray(block)
    if not (block.flags.c_contiguous and block.dtype == little):
        nbytes = block.size * little.itemsize
        buf = getattr(_ENCODE, "buf", None)
        if buf is None or buf.size < nbytes:
            buf = _ENCODE.buf = np.empty(nbytes, np.uint8)
        dest = buf[:nbytes].view(little).reshape(block.shape)
        np.copyto(dest, block, casting="unsafe")
        block = dest
    return Zstd(level=level).encode(block)


_ENCODE = threading.local()  # encode_chunk's per-thread buffer


def decode_chunk(payload: bytes, dtype, chunk_shape, scratch: bool = False,
                 out: np.ndarray | None = None) -> np.ndarray:
    """The inverse of :func:`encode_chunk`: a stored chunk's array (read-only view).

    ``scratch``: decode into this thread's reusable buffer instead of fresh memory (a 0.05 m
    chunk is 4 MB: fresh pages cost as much as the decoding); the array is then valid only until
    the thread's next scratch decode, so copy it out at once. ``out``: decode into this
    C-contiguous array of the chunk's shape and dtype instead (e.g. a block of a frame buffer)."""
    little = np.dtype(dtype).newbyteorder("<")
    if not scratch and out is None:
        return np.frombuffer(Zstd().decode(payload), dtype=little).reshape(chunk_shape)
    nbytes = math.prod(chunk_shape) * little.itemsize
    # zstd fills what it decodes and leaves the rest of a reused buffer as it was: a chunk that
    # declares another size must fail here as it does on fresh memory (one that decodes to more
    # than it declares, or to more than the buffer, fails in the decoder)
    if zstd_content_size(payload) != nbytes:
        raise ValueError(f"not a zstd frame of {nbytes} bytes")
    if out is not None:
        if out.nbytes != nbytes or not out.flags.c_contiguous or out.dtype.itemsize != little.itemsize:
            raise ValueError(f"out ({out.shape} {out.dtype}) does not fit a chunk of {tuple(chunk_shape)} {little}")
        Zstd().decode(payload, out=out.reshape(-1).view(np.uint8))
        return out
    buf = getattr(_SCRATCH, "buf", None)
    if buf is None or buf.size < nbytes:
        buf = _SCRATCH.buf = np.empty(nbytes, np.uint8)
    dest = buf[:nbytes]
    Zstd().decode(payload, out=dest)
    return dest.view(little).reshape(chunk_shape)


def zstd_content_size(payload: bytes) -> int | None:
    """The content size the first zstd frame of ``payload`` declares in its header (RFC 8878),
    or None when ``payload`` does not start with a zstd frame or the header gives no size. Reads
    a few header bytes only (:func:`zstd_frame_ok` walks every block)."""
    if len(payload) < 6 or int.from_bytes(payload[:4], "little") != 0xFD2FB528:
        return None
    fhd = payload[4]
    fcs_flag, single, dict_flag = fhd >> 6, (fhd >> 5) & 1, fhd & 3
    fcs_len = (1 if single else 0) if fcs_flag == 0 else (2, 4, 8)[fcs_flag - 1]
    pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[dict_flag]
    if fcs_len == 0 or pos + fcs_len > len(payload):
        return None
    return int.from_bytes(payload[pos:pos + fcs_len], "little") + (256 if fcs_len == 2 else 0)


_SCRATCH = threading.local()  # decode_chunk's per-thread buffer


def get_object(store: Store, key: str) -> bytes | None:
    """The bytes of one stored object (a chunk), or None when it is not stored (an all-zero chunk)."""
    try:
        if store.is_local:  # a plain read: fsspec's per-call path handling costs as much at 0.05 m
            with open(store.path(key), "rb") as f:
                return f.read()
        return store.fs.cat_file(store.path(key))
    except (FileNotFoundError, NotADirectoryError):
        return None


def put_object(store: Store, key: str, payload: bytes, new_directory: bool = False) -> None:
    """Store one object (a chunk) under a store-relative key; a reader never sees half of it
    (local: a temporary ``.chunk-*`` file renamed into place). ``new_directory``: the caller
    expects the object's directory not to exist yet (a frame written for the first time: in Zarr
    v3's layout a chunk of a 4-d array is the only file of its directory), so it is created
    before the write instead of after a failed one; either way an existing directory is used
    without a ``mkdir``."""
    if store.is_local:
        path = store.path(key)
        directory = os.path.dirname(path)
        # os.open with 0o666, not tempfile.mkstemp: its 0600 would stick to the chunk, ignoring the
        # umask, and another user of a shared root could not read it
        tmp = os.path.join(directory, f".chunk-{uuid.uuid4().hex}")
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL
        if new_directory:
            os.makedirs(directory, exist_ok=True)
        try:
            fd = os.open(tmp, flags, 0o666)
        except FileNotFoundError:  # the directory is missing: made here, once, by its first chunk
            os.makedirs(directory, exist_ok=True)
            fd = os.open(tmp, flags, 0o666)
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


DAMAGED = "damaged: "  # the prefix of the fingerprint of a frame with an unreadable part


def is_damaged(fingerprint: str | None) -> bool:
    """The fingerprint says the frame could not be read (see :func:`frame_fingerprint`)."""
    return fingerprint is not None and fingerprint.startswith(DAMAGED)


def damaged(where: str, problem: str = "unreadable") -> str:
    """The fingerprint of a frame whose ``where`` (a store-relative path) cannot be read."""
    return f"{DAMAGED}{where} {problem}"


def parse_metadata(raw: bytes, node_type: str | None = None) -> dict | None:
    """Zarr v3 metadata from the bytes of a ``zarr.json``, or None when they are not (truncated
    or garbage bytes, another format, not a ``node_type`` node when given)."""
    try:
        meta = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(meta, dict) or meta.get("zarr_format") != 3 or meta.get("node_type") not in ("array", "group"):
        return None
    if node_type is not None and meta["node_type"] != node_type:
        return None
    if meta["node_type"] == "array":
        try:
            chunks = meta["chunk_grid"]["configuration"]["chunk_shape"]
            ok = (isinstance(meta["shape"], list) and isinstance(chunks, list) and len(chunks) == len(meta["shape"])
                  and all(isinstance(v, int) and v >= 0 for v in meta["shape"] + chunks)
                  and isinstance(meta["data_type"], str) and isinstance(meta["codecs"], list))
        except (KeyError, TypeError):
            ok = False
        if not ok:
            return None
    return meta


def metadata_problem(store: Store, node: str, node_type: str | None = None) -> str | None:
    """What is wrong with the metadata of the Zarr node at store-relative path ``node`` (e.g.
    ``occupancy.zarr`` or ``occupancy.zarr/<seq>/<voxel_size>/semantic``): ``"missing"`` (no
    ``zarr.json``), ``"unreadable"`` (not Zarr v3 metadata of a ``node_type`` node), or None."""
    try:
        raw = store.fs.cat_file(store.path(f"{node}/zarr.json"))
    except FileNotFoundError:
        return "missing"
    except OSError:  # a directory named zarr.json, no permission...
        return "unreadable"
    return None if parse_metadata(raw, node_type) is not None else "unreadable"


def ancestor_groups(zarr_root: str, array_path: str) -> list[str]:
    """Store-relative paths of the groups above an array, from the hierarchy's root down."""
    parts = array_path.split("/")[:-1]
    return [zarr_root] + [f"{zarr_root}/{'/'.join(parts[:i + 1])}" for i in range(len(parts))]


def zstd_frame_ok(payload: bytes, content_size: int | None = None) -> bool:
    """``payload`` is whole zstd frames (RFC 8878): magic numbers, frame headers and every block
    header within the bytes, nothing after the last frame; when the header gives the content size
    it equals ``content_size`` (if given). Walks the block headers without decompressing, so a
    truncated chunk or garbage bytes are found cheaply (a bit flipped inside a compressed block
    is not: that changes the frame's fingerprint all the same)."""
    data = memoryview(payload)
    n, pos, frames = len(data), 0, 0
    while pos < n:
        if n - pos < 4:
            return False
        magic = int.from_bytes(data[pos:pos + 4], "little")
        if 0x184D2A50 <= magic <= 0x184D2A5F:  # a skippable frame
            if n - pos < 8:
                return False
            pos += 8 + int.from_bytes(data[pos + 4:pos + 8], "little")
            if pos > n:
                return False
            continue
        if magic != 0xFD2FB528 or n - pos < 5:
            return False
        fhd = data[pos + 4]
        fcs_flag, single, checksum, dict_flag = fhd >> 6, (fhd >> 5) & 1, (fhd >> 2) & 1, fhd & 3
        if fhd & 0x08:  # the reserved bit
            return False
        fcs_len = (1 if single else 0) if fcs_flag == 0 else (2, 4, 8)[fcs_flag - 1]
        pos += 5 + (0 if single else 1) + (0, 1, 2, 4)[dict_flag]
        if pos + fcs_len > n:
            return False
        if fcs_len and content_size is not None:
            fcs = int.from_bytes(data[pos:pos + fcs_len], "little") + (256 if fcs_len == 2 else 0)
            if fcs != content_size:
                return False
        pos += fcs_len
        while True:
            if pos + 3 > n:
                return False
            header = int.from_bytes(data[pos:pos + 3], "little")
            last, kind, size = header & 1, (header >> 1) & 3, header >> 3
            if kind == 3:  # reserved block type
                return False
            pos += 3 + (1 if kind == 1 else size)
            if pos > n:
                return False
            if last:
                break
        pos += 4 if checksum else 0
        if pos > n:
            return False
        frames += 1
    return frames > 0


def _is_zstd_array(meta: dict) -> bool:
    """The array's chunks are stored as :func:`encode_chunk` writes them (bytes, then zstd)."""
    names = [c.get("name") if isinstance(c, dict) else None for c in meta["codecs"]]
    return names == ["bytes", "zstd"]


def _chunk_nbytes(meta: dict) -> int | None:
    try:
        itemsize = np.dtype(meta["data_type"]).itemsize
    except TypeError:
        return None
    return int(np.prod(meta["chunk_grid"]["configuration"]["chunk_shape"])) * itemsize


def frame_fingerprint(store: Store, zarr_root: str, array_path: str, frame: int,
                      checked: dict[str, str | None] | None = None) -> str | None:
    """Fingerprint of one frame of an array as stored: the array metadata (``zarr.json``), then
    the names and encoded bytes of its chunk files under ``<array>/c/<frame>`` (all-empty chunks
    are not stored; dot-prefixed temporary files are skipped). Cheap (compressed bytes) and
    sensitive to a deleted, truncated or rewritten chunk; None when the array does not exist.

    A frame that cannot be read gets ``damaged: <path> unreadable`` (see :func:`is_damaged`): its
    array's metadata or that of a group above it is unreadable or (a group's) missing, or one of
    its chunks is not a whole zstd frame of the chunk's size. ``checked`` caches the groups'
    verdicts between calls (node path -> problem or None)."""
    fs, base = store.fs, store.path(f"{zarr_root}/{array_path}")
    where = f"{zarr_root}/{array_path}"
    try:
        meta = fs.cat_file(f"{base}/zarr.json")
    except FileNotFoundError:
        return None
    except OSError:  # a directory named zarr.json, no permission...
        return damaged(f"{where}/zarr.json")
    parsed = parse_metadata(meta, "array")
    if parsed is None:
        return damaged(f"{where}/zarr.json")
    checked = {} if checked is None else checked
    for group in ancestor_groups(zarr_root, array_path):
        if group not in checked:
            checked[group] = metadata_problem(store, group, "group")
        if checked[group] is not None:
            return damaged(f"{group}/zarr.json", checked[group])
    check = _is_zstd_array(parsed)
    nbytes = _chunk_nbytes(parsed) if check else None
    h = hashlib.sha256(meta)
    prefix = f"{base}/c/{frame}"
    for name in _frame_files(store, prefix):
        if name.rsplit("/", 1)[-1].startswith("."):
            continue  # a temporary chunk left by a crashed write is not part of the frame
        payload = _read(store, prefix + name)
        if check and not zstd_frame_ok(payload, nbytes):
            return damaged(f"{where}/c/{frame}{name}")
        h.update(name.encode())
        h.update(payload)
    return "sha256:" + h.hexdigest()[:24]


def _frame_files(store: Store, prefix: str) -> list[str]:
    """The files under the directory (or object prefix) ``prefix`` of a frame's chunks, as their
    names after ``prefix`` (``/<ci>/<cj>...``), sorted as strings. A local store is walked with
    ``os.scandir`` (fsspec's per-entry path handling cost ~0.1 s a 0.05 m frame)."""
    if not store.is_local:
        return sorted(f[len(prefix):] for f in store.find(prefix))
    out: list[str] = []
    stack = [""]
    while stack:
        rel = stack.pop()
        try:
            entries = list(os.scandir(prefix + rel))
        except FileNotFoundError:
            continue
        except NotADirectoryError:  # the prefix itself is a file (damage): listed, as fsspec's find does
            out.append(rel)
            continue
        for e in entries:
            if e.is_dir():
                stack.append(f"{rel}/{e.name}")
            else:
                out.append(f"{rel}/{e.name}")
    return sorted(out)


def _read(store: Store, path: str) -> bytes:
    """The bytes of the file or object at the filesystem path ``path`` of ``store``."""
    if store.is_local:
        with open(path, "rb") as f:
            return f.read()
    return store.fs.cat_file(path)
