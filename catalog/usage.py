"""How much a dataset root holds: bytes and files per part of the store layout."""

from __future__ import annotations

import os
import posixpath
from dataclasses import dataclass

from carlaocc.catalog.store import LIDAR_DIR, LIDAR_RECORDED_DIR, OCCUPANCY_ZARR, SENSORS_ZARR, Store

# the top-level parts of the layout (docs/architecture.md "Store layout"), in the order a report lists them
STORE_PARTS: tuple[str, ...] = ("admesh", "scenes", OCCUPANCY_ZARR, SENSORS_ZARR, LIDAR_DIR, LIDAR_RECORDED_DIR, "metrics",
                                 "catalog")
OTHER = "other"


@dataclass(frozen=True)
class PartUsage:
    part: str
    files: int
    bytes: int


def _walk(store: Store):
    """(store-relative path, bytes) of every file; a local root through ``os.scandir`` (fsspec's
    ``find`` costs ~0.4 ms a file, a dataset has thousands of chunk files)."""
    root = store.root
    if store.is_local:
        if not os.path.isdir(root):
            return
        stack = [root]
        while stack:
            with os.scandir(stack.pop()) as it:
                for entry in it:
                    if entry.is_dir(follow_symlinks=False):
                        stack.append(entry.path)
                    elif entry.is_file():
                        yield os.path.relpath(entry.path, root).replace(os.sep, "/"), entry.stat().st_size
        return
    fs = store.fs
    if not fs.exists(root):
        return
    for path, info in fs.find(root, detail=True).items():
        yield posixpath.relpath(path, root), int(info.get("size") or 0)


def store_usage(store: Store, exclude: tuple[str, ...] = ()) -> list[PartUsage]:
    """Files and bytes under each of :data:`STORE_PARTS` (anything else under ``other``), in that
    order, parts without files left out. Temporary files (``.tmp-*``, ``.chunk-*``) are not
    counted, nor the store-relative paths in ``exclude`` (files, or directories with what is
    under them)."""
    files, sizes = dict.fromkeys((*STORE_PARTS, OTHER), 0), dict.fromkeys((*STORE_PARTS, OTHER), 0)
    excluded = tuple(e.rstrip("/") for e in exclude)
    for rel, size in _walk(store):
        name = posixpath.basename(rel)
        if name.startswith((".tmp-", ".chunk-")):
            continue
        if any(rel == e or rel.startswith(e + "/") for e in excluded):
            continue
        top = rel.split("/", 1)[0]
        part = top if top in files and "/" in rel else OTHER
        files[part] += 1
        sizes[part] += size
    return [PartUsage(p, files[p], sizes[p]) for p in (*STORE_PARTS, OTHER) if files[p]]
