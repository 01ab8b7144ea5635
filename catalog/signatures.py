"""Stat signatures: what the store says about a recorded output without reading its bytes.

A task's outputs are recorded in lineage with their content fingerprints (sha256 of the bytes,
:func:`carlaocc.catalog.zarrio.frame_fingerprint` for a Zarr frame), computed when they are written.
Re-hashing them to decide whether a partition is up to date would read the whole dataset (about
a terabyte at the paper's scale), so the driver also records each output's *signature*: for a
file, its size, modification time and inode on a local disk, or the object store's ETag where it
has one; for a Zarr frame (``<root>.zarr/<array>[<frame>]``), the same for its array's
``zarr.json`` and every stored chunk of the frame, from one directory listing. ``status`` and
``run`` trust a recorded fingerprint while the signature is unchanged and only re-hash outputs
whose signature moved; ``carlaocc verify`` re-hashes everything.

An output edited in place within one tick of the kernel's clock, keeping its size and inode,
keeps its signature: that is what ``verify`` is for.
"""

from __future__ import annotations

import hashlib
import os
import posixpath

from carlaocc.catalog.store import Store
from carlaocc.catalog.zarrio import parse_frame_key

# keys of an fsspec info dict that identify an object's version, most specific first
_VERSION_KEYS = ("ETag", "etag", "e_tag", "md5Hash", "generation", "VersionId")
_TIME_KEYS = ("mtime", "LastModified", "last_modified", "updated", "created")


def info_signature(info: dict) -> str:
    """The signature of one object from its fsspec ``info`` dict: ``etag:<ETag>`` where the store
    gives one (S3, GCS, Azure), else ``<size>:<modification time>``."""
    for key in _VERSION_KEYS:
        if info.get(key):
            return f"etag:{str(info[key]).strip(chr(34))}"
    when = next((info[k] for k in _TIME_KEYS if info.get(k) is not None), "")
    if hasattr(when, "isoformat"):
        when = when.isoformat()
    return f"{info.get('size')}:{when}"


def _local_signature(st: os.stat_result) -> str:
    # size, modification time in ns and inode: a chunk rewritten by rename is a new inode
    return f"{st.st_size}:{st.st_mtime_ns}:{st.st_ino}"


def file_signature(store: Store, rel: str) -> str | None:
    """The signature of a stored file (store-relative path), or None when it does not exist."""
    path = store.path(rel)
    try:
        if store.is_local:
            return _local_signature(os.stat(path))
        return info_signature(store.fs.info(path))
    except FileNotFoundError:
        return None


def _local_tree(base: str) -> list[tuple[str, str]]:
    """(path relative to ``base``, signature) of every file under a local directory, skipping
    dot-prefixed temporaries, in sorted order; one ``scandir`` per directory."""
    out: list[tuple[str, str]] = []
    stack = [""]
    while stack:
        rel = stack.pop()
        try:
            entries = list(os.scandir(os.path.join(base, rel) if rel else base))
        except FileNotFoundError:
            continue
        for e in entries:
            if e.name.startswith("."):
                continue
            name = f"{rel}/{e.name}" if rel else e.name
            if e.is_dir(follow_symlinks=False):
                stack.append(name)
            else:
                out.append((name, _local_signature(e.stat(follow_symlinks=False))))
    return sorted(out)


def frame_signature(store: Store, zarr_root: str, array_path: str, frame: int) -> str | None:
    """The signature of one frame of a Zarr array: its array's ``zarr.json`` and the names and
    signatures of the chunks stored under ``<array>/c/<frame>``, hashed; None when the array has
    no metadata. Reads no chunk (a directory listing and one ``stat`` per chunk)."""
    base = store.path(f"{zarr_root}/{array_path}")
    meta = file_signature(store, f"{zarr_root}/{array_path}/zarr.json")
    if meta is None:
        return None
    h = hashlib.sha256(meta.encode())
    prefix = f"{base}/c/{frame}"
    if store.is_local:
        entries = _local_tree(prefix)
    else:
        fs = store.fs
        found = fs.find(prefix, detail=True) if fs.exists(prefix) else {}
        entries = sorted((p[len(prefix):].lstrip("/"), info_signature(info)) for p, info in found.items()
                         if not posixpath.basename(p).startswith("."))
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
        import fsspec

        fs, p = fsspec.core.url_to_fs(path)
        return info_signature(fs.info(p))
    except (OSError, ValueError):
        return None
