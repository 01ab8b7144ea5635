"""Stat signatures: what the store says about a recorded output without reading its bytes.

A task's outputs are recorded in lineage with their content fingerprints (sha256 of the bytes,
:func:`carlaocc.catalog.zarrio.frame_fingerprint` for a Zarr frame), computed when they are written.
Re-hashing them to decide whether a partition is up to date would read the whole dataset (about
a terabyte at the paper's scale), so the driver also records each output's *signature*: for a
file, its size, modification time, inode and status-change time (ctime) on a local disk, or the object store's ETag where it
has one; for a Zarr frame (``<root>.zarr/<array>[<frame>]``), the same for its array's
``zarr.json`` and every chunk the frame can have (one ``stat`` each; a listing on object stores). ``status`` and
``run`` trust a recorded fingerprint while the signature is unchanged and only re-hash outputs
whose signature moved; ``carlaocc verify`` re-hashes everything.

The ctime is what no user-level tool can set: an output edited in place and given its old
modification time back (``touch -r``, a sync tool preserving times) has a new ctime, so its
signature moves and it is re-hashed. What moves the ctime without touching the bytes (``chmod``,
``chown``, a hard-linked snapshot ``cp -al``, which adds a link to every inode) is re-hashed too,
found intact and reported clean, never rebuilt; ``carlaocc verify`` then records the new
signatures so ``status`` is cheap again. Only an edit within one tick of the kernel's clock (a few
ms) that keeps size, inode and both times escapes the signature: that is what ``verify`` is for.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import posixpath

import fsspec

from carlaocc.catalog.store import Store
from carlaocc.catalog.zarrio import parse_frame_key, parse_metadata

# keys of an fsspec info dict that identify an object's version, most specific first
_VERSION_KEYS = ("ETag", "etag", "e_tag", "md5Hash", "generation", "VersionId")
_TIME_KEYS = ("mtime", "LastModified", "last_modified", "updated", "created")


def info_signature(info: dict) -> str | None:
    """The signature of one object from its fsspec ``info`` dict: ``etag:<ETag>`` where the store
    gives one (S3, GCS, Azure), else ``<size>:<modification time>``; None (never trusted: the
    object is hashed) when the store gives neither a version nor a time."""
    for key in _VERSION_KEYS:
        if info.get(key):
            return f"etag:{str(info[key]).strip(chr(34))}"
    when = next((info[k] for k in _TIME_KEYS if info.get(k) is not None), None)
    if when is None:
        return None
    if hasattr(when, "isoformat"):
        when = when.isoformat()
    return f"{info.get('size')}:{when}"


def _local_signature(st: os.stat_result) -> str:
    # size, modification time in ns and inode (a chunk rewritten by rename is a new inode), and
    # the status-change time, which an in-place edit moves whatever times it restores
    return f"{st.st_size}:{st.st_mtime_ns}:{st.st_ino}:{st.st_ctime_ns}"


def file_signature(store: Store, rel: str) -> str | None:
    """The signature of a stored file (store-relative path), or None when it does not exist."""
    path = store.path(rel)
    try:
        if store.is_local:
            return _local_signature(os.stat(path))
        return info_signature(store.fs.info(path))
    except FileNotFoundError:
        return None


_CHUNK_GRIDS: dict[tuple[str, str], tuple[int, ...] | None] = {}  # (zarr.json, its signature) -> chunks per axis


def _chunk_grid(store: Store, meta_rel: str, meta_sig: str) -> tuple[int, ...] | None:
    """Chunks along each axis after the frame axis of the array whose metadata is ``meta_rel``
    (read once per version of the file), None when it is not an array's Zarr v3 metadata."""

    key = (store.path(meta_rel), meta_sig)
    if key not in _CHUNK_GRIDS:
        try:
            meta = parse_metadata(store.fs.cat_file(store.path(meta_rel)), "array")
        except OSError:
            meta = None
        if meta is None or len(meta["shape"]) < 2:
            _CHUNK_GRIDS[key] = None
        else:
            chunks = meta["chunk_grid"]["configuration"]["chunk_shape"]
            _CHUNK_GRIDS[key] = tuple(-(-n // max(1, c)) for n, c in zip(meta["shape"][1:], chunks[1:]))
    return _CHUNK_GRIDS[key]


def _local_chunks(base: str, frame: int, grid: tuple[int, ...]) -> list[tuple[str, str]]:
    """(chunk key, signature or "-" when not stored) of every chunk a frame can have: one
    ``stat`` each, no directory listing (a frame's chunk directories nest one level per axis)."""

    out = []
    for idx in itertools.product(*(range(n) for n in grid)):
        name = "/".join(map(str, idx))
        try:
            out.append((name, _local_signature(os.stat(f"{base}/c/{frame}/{name}"))))
        except FileNotFoundError:
            out.append((name, "-"))
        except NotADirectoryError:
            return []  # a file where a chunk directory should be: hashed, never trusted
    return out


def frame_signature(store: Store, zarr_root: str, array_path: str, frame: int) -> str | None:
    """The signature of one frame of a Zarr array: its array's ``zarr.json`` and the names and
    signatures of the chunks stored under ``<array>/c/<frame>``, hashed; None when the array has
    no metadata. Reads no chunk: on a local disk one ``stat`` per chunk the array's chunk grid
    allows (stored or not), elsewhere one listing of the frame's chunks."""
    base = store.path(f"{zarr_root}/{array_path}")
    meta = file_signature(store, f"{zarr_root}/{array_path}/zarr.json")
    if meta is None:
        return None  # no array there (or no signature for its metadata): never trusted
    h = hashlib.sha256(meta.encode())
    prefix = f"{base}/c/{frame}"
    if store.is_local:
        grid = _chunk_grid(store, f"{zarr_root}/{array_path}/zarr.json", meta)
        entries = _local_chunks(base, frame, grid) if grid is not None else []
        if not entries:
            return None
    else:
        fs = store.fs
        found = store.find(prefix, detail=True)
        entries = sorted((p[len(prefix):].lstrip("/"), info_signature(info)) for p, info in found.items()
                         if not posixpath.basename(p).startswith("."))
        if any(sig is None for _, sig in entries):
            return None  # a chunk the store gives no version or time for: never trusted
    for name, sig in entries:
        h.update(f"\0{name}\0{sig}".encode())
    return "stat:" + h.hexdigest()[:24]


def output_signature(store: Store, key: str) -> str | None:
    """The signature of one lineage output key: a Zarr frame key or a store-relative file."""
    frame = parse_frame_key(key)
    try:
        return file_signature(store, key) if frame is None else frame_signature(store, *frame)
    except OSError:  # no permission, a directory where a file was...: never trusted
        return None


def output_signatures(store: Store, outputs: dict[str, str]) -> dict[str, str]:
    """Key -> signature of a task's recorded outputs (those that exist)."""
    out = {}
    for key in outputs:
        sig = output_signature(store, key)
        if sig is not None:
            out[key] = sig
    return out


def external_signature(path: str) -> str | None:
    """The signature of an external input file (a local path or fsspec URL), None when it cannot
    be had: the recorded fingerprint of a source file is trusted while this is unchanged."""
    try:
        if "://" not in path or path.startswith("file://"):
            return _local_signature(os.stat(path.removeprefix("file://")))

        fs, p = fsspec.core.url_to_fs(path)
        return info_signature(fs.info(p))
    except (OSError, ValueError):
        return None
