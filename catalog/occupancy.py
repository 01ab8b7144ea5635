"""Occupancy volumes in Zarr v3: ``occupancy.zarr/<sequence>/<res>/{semantic,instance}``.

Each array is ``(frame, x, y, z)``; a chunk is one frame's ``chunk_edge x chunk_edge x Z`` column
block, so a task that writes one whole frame writes whole chunks and no two tasks ever touch the
same chunk. Arrays are created by the driver before any task runs (:meth:`OccupancyStore.create`)
and carry the grid spec, voxel size, origin, frame and taxonomy version in their attributes.
"""

from __future__ import annotations

import hashlib

import numpy as np
import zarr
from zarr.storage import FsspecStore, LocalStore

from catalog.store import OCCUPANCY_ZARR, Store
from schemas.grid import GridSpec
from schemas.taxonomy import TAXONOMY_VERSION

# array name -> dtype, description
OCCUPANCY_ARRAYS: dict[str, tuple[str, str]] = {
    "semantic": ("uint8", "semantic class id per voxel (0 = free), CarlaOcc 30-class taxonomy"),
    "instance": ("uint32", "instance id per voxel, unique within the sequence (0 = stuff or free)"),
}


def parse_output_key(key: str) -> tuple[str, int] | None:
    """``occupancy.zarr/<seq>/<res>/<name>[<frame>]`` -> (array path, frame); None otherwise."""
    if not (key.startswith(OCCUPANCY_ZARR + "/") and key.endswith("]") and "[" in key):
        return None
    path, frame = key[len(OCCUPANCY_ZARR) + 1 : -1].rsplit("[", 1)
    return path, int(frame)


def zarr_store(store: Store, name: str):
    """A zarr store object over ``<root>/<name>`` (local directory or fsspec URL)."""
    if store.is_local:
        return LocalStore(store.path(name))
    return FsspecStore.from_url(store.uri(name))


class OccupancyStore:
    """The occupancy Zarr hierarchy of a store."""

    def __init__(self, store: Store):
        self.store = store

    def _root(self, mode: str) -> zarr.Group:
        return zarr.open_group(store=zarr_store(self.store, OCCUPANCY_ZARR), mode=mode)

    @staticmethod
    def array_path(sequence_id: str, grid: GridSpec, name: str) -> str:
        return f"{sequence_id}/{grid.key}/{name}"

    def output_key(self, sequence_id: str, grid: GridSpec, name: str, frame: int) -> str:
        """Lineage key of one frame of one array: ``occupancy.zarr/<seq>/<res>/<name>[<frame>]``."""
        return f"{OCCUPANCY_ZARR}/{self.array_path(sequence_id, grid, name)}[{frame}]"

    def create(self, sequence_id: str, grid: GridSpec, frame_count: int, chunk_edge: int,
               extra_attrs: dict | None = None) -> bool:
        """Create (or keep, when identical) the arrays of one sequence at one resolution.

        An existing array with the same shape, dtype, chunks and attributes is kept with its
        data; one that differs (another region, frame count, taxonomy...) is replaced, and then
        every frame of it must be written again: returns True when an existing array was replaced.
        """
        replaced = False
        root = self._root("a")
        X, Y, Z = grid.shape
        shape = (frame_count, X, Y, Z)
        chunks = (1, min(chunk_edge, X), min(chunk_edge, Y), Z)
        attrs = {
            **grid.attrs(),
            "dims": ["frame", "x", "y", "z"],
            "sequence_id": sequence_id,
            "taxonomy_version": TAXONOMY_VERSION,
            **(extra_attrs or {}),
        }
        for name, (dtype, description) in OCCUPANCY_ARRAYS.items():
            path = self.array_path(sequence_id, grid, name)
            want = {**attrs, "description": description}
            if path in root:
                arr = root[path]
                if (isinstance(arr, zarr.Array) and arr.shape == shape and arr.chunks == chunks
                        and str(arr.dtype) == dtype and dict(arr.attrs) == want):
                    continue
                replaced = True
            root.create_array(path, shape=shape, chunks=chunks, dtype=dtype, fill_value=0,
                              overwrite=True, attributes=want)
        return replaced

    def exists(self, sequence_id: str, grid: GridSpec, name: str, frame: int | None = None) -> bool:
        try:
            arr = self._root("r")[self.array_path(sequence_id, grid, name)]
        except (KeyError, FileNotFoundError, zarr.errors.GroupNotFoundError):
            return False
        return frame is None or 0 <= frame < arr.shape[0]

    def open(self, sequence_id: str, grid: GridSpec, name: str, mode: str = "r") -> zarr.Array:
        root = self._root(mode)
        return root[self.array_path(sequence_id, grid, name)]

    def write_frame(self, sequence_id: str, grid: GridSpec, frame: int,
                    arrays: dict[str, np.ndarray]) -> dict[str, str]:
        """Write one frame of each array (whole chunks); returns lineage key -> fingerprint of
        the frame's encoded chunks (see :meth:`frame_fingerprint`)."""
        out = {}
        for name, data in arrays.items():
            arr = self.open(sequence_id, grid, name, mode="r+")
            if data.shape != arr.shape[1:]:
                raise ValueError(f"{name}: frame shape {data.shape} != array {arr.shape[1:]}")
            arr[frame] = data.astype(arr.dtype, copy=False)
            path = self.array_path(sequence_id, grid, name)
            out[f"{OCCUPANCY_ZARR}/{path}[{frame}]"] = self.frame_fingerprint(path, frame)
        return out

    def frame_fingerprint(self, array_path: str, frame: int) -> str | None:
        """Fingerprint of one frame as stored: the names and encoded bytes of its chunk files
        (``<array>/c/<frame>/...``; all-empty chunks are not stored), plus the array metadata.
        Cheap (compressed bytes) and sensitive to a deleted, truncated or rewritten chunk;
        None when the array does not exist."""
        fs, base = self.store.fs, self.store.path(f"{OCCUPANCY_ZARR}/{array_path}")
        try:
            meta = fs.cat_file(f"{base}/zarr.json")
        except FileNotFoundError:
            return None
        h = hashlib.sha256(meta)
        prefix = f"{base}/c/{frame}"
        files = sorted(fs.find(prefix)) if fs.exists(prefix) else []
        for f in files:
            h.update(f[len(prefix):].encode())
            h.update(fs.cat_file(f))
        return "sha256:" + h.hexdigest()[:24]

    def read_frame(self, sequence_id: str, grid: GridSpec, frame: int,
                   names: tuple[str, ...] = ("semantic", "instance")) -> dict[str, np.ndarray]:
        return {n: self.open(sequence_id, grid, n)[frame] for n in names}
