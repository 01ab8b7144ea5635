"""Frame-indexed Zarr v3 arrays: the base of the store's Zarr hierarchies (:class:`FrameArrayStore`).

A hierarchy ``<root>.zarr/<sequence>/<group>/<name>`` (``occupancy.zarr/<seq>/<voxel_size>/...``,
``sensors.zarr/<seq>/<camera>/...``) holds arrays ``(frame, a, b, ...)`` chunked
``(1, ca, cb, <whole rest>)``: a chunk is one frame's ``ca x cb`` block of the first two axes after
the frame (x, y of a voxel grid; v, u of an image) with every other axis whole, so a task that
writes one frame writes whole chunks and no two tasks touch the same chunk. This module holds
what both hierarchies share: creating the arrays (an identical array is kept with its data, a
differing one replaced), opening them, ``exists``, writing and reading a frame's chunks (encoded
and decoded by :mod:`carlaocc.catalog.zarrio`, all-zero chunks not stored) and the lineage keys
and fingerprints of a frame. A subclass says what is its own: the root, the array table, the
group key (:meth:`FrameArrayStore.array_path`) and the attributes.

Damaged metadata is repaired by creation (:meth:`FrameArrayStore._repair_metadata`): an unreadable
``zarr.json`` of a group is written again (its arrays kept), an array whose ``zarr.json`` is
unreadable is created anew (its frames must be written again), so a stage's ``prepare`` rebuilds
what a damaged store lost. Reading a damaged node is a :class:`StoreError` naming it.
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod

from collections.abc import Callable, Iterable
from typing import ClassVar

import numpy as np
import zarr
from numba import njit
from zarr.codecs import ZstdCodec

from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.zarrio import (ZSTD_LEVEL, ancestor_groups, decode_chunk, encode_chunk, frame_fingerprint,
                                     get_object, metadata_problem, parse_metadata, put_object, remove_object,
                                     zarr_store)

# zarr's errors for a node that is not there (the node itself, or the whole hierarchy)
_MISSING = (KeyError, FileNotFoundError, zarr.errors.GroupNotFoundError)


@njit(cache=True, nogil=True)
def _any_run(b, b64, start, end):  # pragma: no cover - numba
    """True when a byte of ``b[start:end]`` is nonzero: unaligned head and tail byte by byte, the
    body OR-reduced as uint64 words (``b64`` views the same buffer)."""
    k = start
    while k < end and k % 8:
        if b[k]:
            return True
        k += 1
    w1 = end // 8
    acc = np.uint64(0)
    for w in range(k // 8, w1):
        acc |= b64[w]
    if acc:
        return True
    for k2 in range(max(k, w1 * 8), end):
        if b[k2]:
            return True
    return False


@njit(cache=True, nogil=True)
def _chunk_flags(b, b64, nx, ny, m, cx, cy, candidates):  # pragma: no cover - numba
    """1 for each (cx, cy) column block of the flat byte volume ``b`` (nx, ny, m bytes per
    column, C order) that holds a nonzero byte, looking only at the blocks flagged in
    ``candidates``; for each x row a block's columns are one contiguous byte run."""
    fy = (ny + cy - 1) // cy
    flags = np.zeros(((nx + cx - 1) // cx, fy), dtype=np.uint8)
    for i in range(nx):
        for cj in range(fy):
            if flags[i // cx, cj] or not candidates[i // cx, cj]:
                continue
            if _any_run(b, b64, (i * ny + cj * cy) * m, (i * ny + min(ny, (cj + 1) * cy)) * m):
                flags[i // cx, cj] = 1
    return flags


def chunk_flags(data: np.ndarray, cx: int, cy: int, candidates: np.ndarray | None = None) -> np.ndarray:
    """Which (x, y) chunks of a tile (nx, ny, ...) hold a nonzero value (bitwise: -0.0 counts).

    ``candidates`` (bool, one per chunk), when given, are the only chunks that may: the others
    are reported empty without reading them."""
    nx, ny = data.shape[:2]
    shape = (-(-nx // cx), -(-ny // cy))
    if candidates is None:
        candidates = np.ones(shape, dtype=np.uint8)
    elif np.shape(candidates) != shape:
        raise ValueError(f"candidates must have one flag per chunk {shape}, got {np.shape(candidates)}")
    b = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    b64 = b[: b.size // 8 * 8].view(np.uint64)  # the buffer start is 8-aligned (numpy allocations are)
    return _chunk_flags(b, b64, nx, ny, b.size // max(nx * ny, 1), cx, cy,
                        np.ascontiguousarray(candidates, dtype=np.uint8))


class FrameArrayStore(ABC):
    """Frame-indexed Zarr v3 arrays ``<zarr_root>/<sequence>/<group>/<name>`` of a store.

    ``group`` is what a subclass places between the sequence and the array name (a
    :class:`~carlaocc.schemas.grid.GridSpec` for occupancy, a camera name for camera maps); every
    method addresses an array as ``(sequence_id, group, name)``. The tile methods work on a range
    ``[x0, x0 + nx)`` of the first axis after the frame, which must cover whole chunks.
    """

    zarr_root: ClassVar[str] = ""
    # array name -> dtype, description, trailing axes (one chunk each, beyond the frame's axes)
    arrays: ClassVar[dict[str, tuple[str, str, tuple[int, ...]]]] = {}
    kind: ClassVar[str] = "arrays"  # what the arrays are called in errors ("occupancy arrays", "camera maps")
    # array name -> zstd level of its chunks, where it is not ZSTD_LEVEL (decoding is the same)
    zstd_levels: ClassVar[dict[str, int]] = {}

    def __init__(self, store: Store):
        self.store = store
        self._layouts: dict[str, tuple[tuple, tuple, np.dtype]] = {}

    # -- addressing ---------------------------------------------------------------------------
    @staticmethod
    @abstractmethod
    def array_path(sequence_id: str, group, name: str) -> str:
        """``<sequence>/<group key>/<name>`` inside the hierarchy: each store's own layout."""

    def output_key(self, sequence_id: str, group, name: str, frame: int) -> str:
        """Lineage key of one frame of one array: ``<root>.zarr/<array path>[<frame>]``."""
        return f"{self.zarr_root}/{self.array_path(sequence_id, group, name)}[{frame}]"

    def _where(self, path: str) -> str:
        return f"{self.zarr_root}/{path}"

    def _root(self, mode: str) -> zarr.Group:
        return zarr.open_group(store=zarr_store(self.store, self.zarr_root), mode=mode)

    def _node(self, path: str):
        """The node at ``path`` of the hierarchy, or None when it (or the hierarchy) is missing;
        StoreError naming it when its metadata cannot be read."""
        try:
            return self._root("r")[path]
        except _MISSING:
            return None
        except ValueError as exc:  # unreadable zarr.json (bad JSON, invalid metadata)
            raise StoreError(f"damaged in the store {self.store.url}: {self._where(path)}: {exc}") from exc

    # -- arrays -------------------------------------------------------------------------------
    def _create_arrays(self, sequence_id: str, group, names: Iterable[str], frame_count: int,
                       frame_shape: tuple[int, ...], chunk_shape: tuple[int, ...], attrs: dict,
                       drop_others: bool = True) -> bool:
        """Create (or keep, when identical) the arrays ``names`` of one group: shape ``(frame_count,
        *frame_shape, *trailing)``, chunks ``(1, *chunk_shape, *trailing)``, attributes ``attrs``
        plus the array's description (and a ``component`` dim when it has trailing axes).

        An existing array with the same shape, dtype, chunks and attributes is kept with its
        data; one that differs is replaced: returns True when an existing array was replaced.
        With ``drop_others``, the group's stale arrays (:meth:`_stale_arrays`) are deleted first.
        """
        names = tuple(names)
        unknown = set(names) - set(self.arrays)
        if unknown:
            raise ValueError(f"unknown {self.kind} {sorted(unknown)}; known: {', '.join(self.arrays)}")
        self._layouts.clear()  # arrays may be recreated with another layout
        replaced, broken_groups = self._repair_metadata(sequence_id, group, names, drop_others)
        root = self._root("a")
        for path in broken_groups:  # written again (the root group was, by opening it)
            root.require_group(path)
        if drop_others:
            for path in self._stale_arrays(root, sequence_id, group, names):
                del root[path]
        for name in names:
            dtype, description, trailing = self.arrays[name]
            path = self.array_path(sequence_id, group, name)
            f_shape, c_shape, dims = self._array_layout(name, frame_shape, chunk_shape, attrs.get("dims"))
            shape = (frame_count, *f_shape, *trailing)
            chunks = (1, *c_shape, *trailing)
            want = {**attrs, "description": description}
            if dims is not None:
                want["dims"] = list(dims)
            if trailing:
                want["dims"] = [*want["dims"], "component"]
            if path in root:
                arr = root[path]
                if (isinstance(arr, zarr.Array) and arr.shape == shape and arr.chunks == chunks
                        and str(arr.dtype) == dtype and dict(arr.attrs) == want):
                    continue
                replaced = True
            root.create_array(path, shape=shape, chunks=chunks, dtype=dtype, fill_value=0,
                              compressors=ZstdCodec(level=self.zstd_levels.get(name, ZSTD_LEVEL)), overwrite=True,
                              attributes=want)
        return replaced

    def _array_layout(self, name: str, frame_shape: tuple[int, ...], chunk_shape: tuple[int, ...],
                      dims: list[str] | None) -> tuple[tuple[int, ...], tuple[int, ...], list[str] | None]:
        """(frame shape, chunk shape, dims) of array ``name`` before its trailing axes: the
        group's own by default; a subclass may give one array another last axis (e.g. bits
        packed along it)."""
        return tuple(frame_shape), tuple(chunk_shape), dims

    def _repair_metadata(self, sequence_id: str, group, names: tuple[str, ...],
                         drop_others: bool) -> tuple[bool, list[str]]:
        """Make the metadata above and at the arrays ``names`` of one group readable before they are
        created: the unreadable ``zarr.json`` of a group above them (the root, the sequence, the
        group) is removed, its arrays kept; an array of ``names`` whose ``zarr.json`` is unreadable is
        deleted with its chunks (created anew: every frame of it must be written again), and with
        ``drop_others`` so is any other node of the group with unreadable metadata (it would be
        deleted as stale anyway; without, e.g. a recorder's ``*_raw`` input, it is left alone).

        Returns (whether an array was deleted, the hierarchy paths of the groups to write again:
        those removed or missing below the root)."""
        parent = self.array_path(sequence_id, group, "_").rsplit("/", 1)[0]
        groups = ancestor_groups(self.zarr_root, f"{parent}/_")
        if not self.store.exists(self.zarr_root):
            return False, []  # a new hierarchy: nothing to repair
        broken: list[str] = []
        for node in groups:
            problem = metadata_problem(self.store, node, "group")
            if problem == "unreadable":
                self.store.remove(f"{node}/zarr.json")  # a file, or whatever took its name
            if problem is not None and node != self.zarr_root:
                broken.append(node[len(self.zarr_root) + 1:])
        deleted = False
        candidates = set(names)
        if drop_others:
            base = self.store.path(f"{self.zarr_root}/{parent}")
            fs = self.store.fs
            if fs.isdir(base):
                candidates |= {p.rstrip("/").rsplit("/", 1)[-1] for p in fs.ls(base, detail=False) if fs.isdir(p)}
        for name in sorted(candidates):
            node = f"{self.zarr_root}/{parent}/{name}"
            if metadata_problem(self.store, node) == "unreadable":  # a readable group is zarr's to replace
                self.store.remove(node)
                deleted = deleted or name in names
        return deleted, broken

    def _stale_arrays(self, root: zarr.Group, sequence_id: str, group, names: tuple[str, ...]) -> list[str]:
        """Paths of the group's arrays that :meth:`_create_arrays` deletes because they are not in
        ``names`` (so nothing stale stays readable): every other array of the group, sorted."""
        parent = self.array_path(sequence_id, group, "_").rsplit("/", 1)[0]
        if parent not in root or not isinstance(root[parent], zarr.Group):
            return []
        return [f"{parent}/{stale}" for stale in sorted(set(root[parent].array_keys()) - set(names))]

    def open(self, sequence_id: str, group, name: str) -> zarr.Array:
        """The zarr array (read-only use); StoreError naming it when missing or damaged."""
        path = self.array_path(sequence_id, group, name)
        arr = self._node(path)
        if not isinstance(arr, zarr.Array):
            raise StoreError(f"missing in the store {self.store.url}: {self._where(path)}")
        return arr

    def attrs(self, sequence_id: str, group, name: str) -> dict:
        """The attributes of one array."""
        return dict(self.open(sequence_id, group, name).attrs)

    def exists(self, sequence_id: str, group, name: str, frame: int | None = None) -> bool:
        """The array exists; with ``frame``: also within its frame count."""
        arr = self._node(self.array_path(sequence_id, group, name))
        if not isinstance(arr, zarr.Array):
            return False
        return frame is None or 0 <= frame < arr.shape[0]

    def _layout(self, sequence_id: str, group, name: str) -> tuple[tuple, tuple, np.dtype]:
        """(shape, chunks, dtype) of an array, read once from its metadata per store object;
        ValueError naming it when it does not exist."""
        path = self.array_path(sequence_id, group, name)
        if path not in self._layouts:
            # the array's zarr.json parsed directly under a readable root (opening the root and the
            # node through zarr-python's event loop cost ~3 ms a call: a sensors task writes 48
            # images); anything else goes through zarr, for its error
            meta = None
            if metadata_problem(self.store, self.zarr_root, "group") is None:
                raw = get_object(self.store, f"{self._where(path)}/zarr.json")
                meta = None if raw is None else parse_metadata(raw, "array")
            if meta is not None and isinstance(meta["data_type"], str):
                try:
                    self._layouts[path] = (tuple(meta["shape"]), tuple(meta["chunk_grid"]["configuration"]["chunk_shape"]),
                                           np.dtype(meta["data_type"]))
                    return self._layouts[path]
                except TypeError:  # a data type numpy does not name the same way
                    pass
            arr = self._node(path)
            if not isinstance(arr, zarr.Array):
                raise ValueError(f"{self._where(path)} does not exist (create it before writing)")
            self._layouts[path] = (tuple(arr.shape), tuple(arr.chunks), np.dtype(arr.dtype))
        return self._layouts[path]

    def chunk_edges(self, sequence_id: str, group, name: str) -> tuple[int, int]:
        """The chunk edges of one array along the two axes after the frame (x, y), in elements."""
        chunks = self._layout(sequence_id, group, name)[1]
        return chunks[1], chunks[2]

    # -- chunks of a frame ----------------------------------------------------------------------
    def _tile_chunks(self, sequence_id: str, group, frame: int, name: str, x0: int, nx: int):
        """(layout, [(ci, cj, key)]) of the chunks of ``[x0, x0 + nx)`` of one frame; the range
        must cover whole chunks (``x0`` on a chunk boundary, the end on one or at the end of the
        array)."""
        shape, chunks, dtype = self._layout(sequence_id, group, name)
        where = self._where(self.array_path(sequence_id, group, name))
        if not 0 <= frame < shape[0]:
            raise ValueError(f"{where}: frame {frame} outside [0, {shape[0]})")
        cx, cy = chunks[1], chunks[2]
        if x0 % cx or not (x0 + nx == shape[1] or (x0 + nx) % cx == 0) or x0 + nx > shape[1]:
            raise ValueError(f"{where}: tile x [{x0}, {x0 + nx}) does not cover whole chunks of {cx}")
        tail = "/0" * (len(shape) - 3)  # the axes beyond the first two (one chunk each)
        keys = [(ci, cj, f"{where}/c/{frame}/{ci}/{cj}{tail}")
                for ci in range(x0 // cx, -(-(x0 + nx) // cx)) for cj in range(-(-shape[2] // cy))]
        return (shape, chunks, dtype), keys

    def _values(self, data: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
        """The data to store in an array of ``dtype`` (a subclass may check or cast it)."""
        return np.asarray(data)

    def write_tile(self, sequence_id: str, group, frame: int, name: str, data: np.ndarray,
                   x0: int, candidates: np.ndarray | None = None) -> None:
        """Write elements ``[x0, x0 + len(data))`` x everything else of one frame of one array.

        The tile must cover whole chunks: ``x0`` on a chunk boundary, and its end on one or at
        the end of the array. Each chunk is encoded (:func:`~carlaocc.catalog.zarrio.encode_chunk`)
        and stored as one object; all-zero chunks (bitwise: -0.0 is data) are removed instead.
        ``candidates`` (bool, x chunks by y chunks of the tile) may say which chunks can hold
        data: the others are known to be zero and are not read.
        """
        shape, _, dtype = self._layout(sequence_id, group, name)
        data = self._values(data, dtype, f"{self._where(self.array_path(sequence_id, group, name))} frame {frame}")
        if data.shape[1:] != shape[2:]:
            raise ValueError(f"{self._where(self.array_path(sequence_id, group, name))}: tile shape {data.shape} "
                             f"does not match the array's {shape[1:]} beyond x")
        cx, cy = self.chunk_edges(sequence_id, group, name)
        # one pass over the tile finds the chunks that hold data (per-block .any() is ~10x slower)
        flags = chunk_flags(data, cx, cy, candidates)

        def block(ci: int, cj: int) -> np.ndarray | None:
            if not flags[ci - x0 // cx, cj]:
                return None
            return data[ci * cx - x0:(ci + 1) * cx - x0, cj * cy:(cj + 1) * cy]

        self.write_chunks(sequence_id, group, frame, name, x0, data.shape[0], block)

    def write_chunks(self, sequence_id: str, group, frame: int, name: str, x0: int, nx: int,
                     block: Callable[[int, int], np.ndarray | None]) -> None:
        """Write the chunks of ``[x0, x0 + nx)`` of one frame of one array (whole chunks, as
        :meth:`write_tile`), each from ``block(ci, cj)``: the chunk's elements (the chunk's
        shape, or what the array holds of it at its edges; encoded without a copy when
        C-contiguous), or None for a chunk that is all zero (then removed)."""
        (shape, chunks, dtype), keys = self._tile_chunks(sequence_id, group, frame, name, x0, nx)
        tail = "/0" * (len(shape) - 3)  # the key's axes beyond x and y (see _tile_chunks)
        little = dtype.newbyteorder("<")
        level = self.zstd_levels.get(name, ZSTD_LEVEL)
        padded = None
        # a local frame's x rows of chunks (directories c/<frame>/<ci>) not there yet: their
        # chunks' directories are made before writing rather than after a failed write
        new_rows: dict[int, bool] = {}
        for ci, cj, key in keys:
            if self.store.is_local and ci not in new_rows:
                row = key[:len(key) - len(f"/{cj}{tail}")]  # <array>/c/<frame>/<ci>
                new_rows[ci] = not os.path.isdir(self.store.path(row))
            data = block(ci, cj)
            if data is None:
                remove_object(self.store, key)
                continue
            if data.shape != chunks[1:]:  # an edge chunk: pad with the fill value
                if padded is None:
                    padded = np.zeros(chunks[1:], dtype=little)
                padded[...] = 0
                padded[:data.shape[0], :data.shape[1]] = data
                data = padded
            put_object(self.store, key, encode_chunk(data, little, level), new_rows.get(ci, False))

    def clear_tile(self, sequence_id: str, group, frame: int, name: str, x0: int, nx: int) -> None:
        """Make ``[x0, x0 + nx)`` of one frame of one array all zero (its chunks are removed); the
        same chunk rules as :meth:`write_tile`, without a zero volume in memory."""
        for _, _, key in self._tile_chunks(sequence_id, group, frame, name, x0, nx)[1]:
            remove_object(self.store, key)

    def write_frame(self, sequence_id: str, group, frame: int, arrays: dict[str, np.ndarray]) -> dict[str, str]:
        """Write one whole frame of each array; returns lineage key -> fingerprint of the frame's
        encoded chunks (see :meth:`fingerprints`)."""
        for name, data in arrays.items():
            self.write_tile(sequence_id, group, frame, name, data, 0)
        return self.fingerprints(sequence_id, group, frame, tuple(arrays))

    def read_tile(self, sequence_id: str, group, frame: int, name: str, x0: int, nx: int,
                  out: np.ndarray | None = None, combine: Callable | None = None) -> np.ndarray:
        """Elements ``[x0, x0 + nx)`` x everything else of one frame of one array: the inverse of
        :meth:`write_tile` (the same whole-chunk rule), each stored chunk decoded directly
        (:func:`~carlaocc.catalog.zarrio.decode_chunk`) and missing ones left at the fill value 0;
        about 4x faster than slicing through zarr-python, which the tests check it agrees with.
        StoreError naming a chunk that cannot be decoded.

        ``out``: a C-contiguous array of the tile's shape and dtype to fill (a buffer reused from
        frame to frame: a new 0.05 m frame is 400 MB of fresh pages to fault in). ``combine``: a
        binary ufunc (e.g. ``np.logical_or`` on bool views) that merges each chunk into ``out``
        instead of overwriting it; missing chunks then leave ``out`` as it is."""
        (shape, chunks, dtype), keys = self._tile_chunks(sequence_id, group, frame, name, x0, nx)
        cx, cy = chunks[1], chunks[2]
        if out is None:
            out = np.zeros((nx, *shape[2:]), dtype=dtype)
            fresh = True
        else:
            if out.shape != (nx, *shape[2:]) or out.dtype.itemsize != np.dtype(dtype).itemsize:
                raise ValueError(f"out has shape {out.shape} and dtype {out.dtype}; the tile has "
                                 f"{(nx, *shape[2:])} {np.dtype(dtype)}")
            fresh = False
        for ci, cj, key in keys:
            xa, ya = ci * cx - x0, cj * cy
            bx, by = min(cx, nx - xa), min(cy, shape[2] - ya)  # edge chunks are padded
            payload = get_object(self.store, key)
            if payload is None:  # an all-zero chunk is not stored
                if not fresh and combine is None:
                    out[xa:xa + bx, ya:ya + by] = 0
                continue
            try:
                # into a reused buffer: the block is copied into out at once
                block = decode_chunk(payload, dtype, chunks[1:], scratch=True)
            except (RuntimeError, ValueError) as exc:  # zstd error, or the wrong decoded size
                raise StoreError(f"damaged chunk in the store {self.store.url}: {key}: {exc}") from exc
            if combine is None:
                out[xa:xa + bx, ya:ya + by] = block[:bx, :by]
            else:
                view = out[xa:xa + bx, ya:ya + by]
                combine(view, block[:bx, :by].view(out.dtype), out=view)
        return out

    def read_blocks(self, sequence_id: str, group, frame: int, name: str, out: np.ndarray | None = None) -> np.ndarray:
        """One whole frame of one array block-major: ``(nbx, nby, cx, cy, *rest)``, block
        ``[ci, cj]`` being chunk ``(ci, cj)`` as stored (edge chunks padded), each stored chunk
        decoded straight into its block (no copy: at 0.05 m copying chunks into an ``(X, Y, Z)``
        frame cost as much as decoding them) and missing ones zero. ``out``: such an array to
        fill (a buffer reused frame after frame); the layout of
        :class:`carlaocc.stages.quality.blocks.BlockedGrid`. StoreError naming a damaged chunk."""
        x_size = self._layout(sequence_id, group, name)[0][1]
        (shape, chunks, dtype), keys = self._tile_chunks(sequence_id, group, frame, name, 0, x_size)
        layout = self.block_layout(sequence_id, group, name)
        if out is None:
            out = np.empty(layout, dtype)
        elif out.shape != layout or out.dtype.itemsize != np.dtype(dtype).itemsize or not out.flags.c_contiguous:
            raise ValueError(f"out has shape {out.shape} and dtype {out.dtype}; the frame's blocks are {layout} "
                             f"{np.dtype(dtype)}")
        for ci, cj, key in keys:
            payload = get_object(self.store, key)
            if payload is None:  # an all-zero chunk is not stored
                out[ci, cj] = 0
                continue
            try:
                decode_chunk(payload, dtype, chunks[1:], out=out[ci, cj])
            except (RuntimeError, ValueError) as exc:  # zstd error, or the wrong decoded size
                raise StoreError(f"damaged chunk in the store {self.store.url}: {key}: {exc}") from exc
        return out

    def block_layout(self, sequence_id: str, group, name: str) -> tuple[int, ...]:
        """The shape :meth:`read_blocks` fills for one frame of one array: ``(nbx, nby, cx, cy, *rest)``."""
        shape, chunks, _ = self._layout(sequence_id, group, name)
        return (-(-shape[1] // chunks[1]), -(-shape[2] // chunks[2]), *chunks[1:])

    def layout(self, sequence_id: str, group, name: str) -> tuple[tuple, tuple, np.dtype]:
        """``(shape, chunks, dtype)`` of one array (ValueError naming it when it does not exist)."""
        return self._layout(sequence_id, group, name)

    def read_chunk(self, sequence_id: str, group, frame: int, name: str, ci: int, cj: int,
                   scratch: bool = False) -> np.ndarray | None:
        """Chunk ``(ci, cj)`` (along the two axes after the frame) of one frame of one array, cut to
        the array's bounds (edge chunks are padded on disk); None when it is not stored (all
        zero). Reads that one object and nothing else. StoreError naming a damaged chunk.
        ``scratch``: decoded into this thread's reused buffer, valid until its next scratch
        decode (:func:`~carlaocc.catalog.zarrio.decode_chunk`)."""
        shape, chunks, dtype = self._layout(sequence_id, group, name)
        where = self._where(self.array_path(sequence_id, group, name))
        cx, cy = chunks[1], chunks[2]
        if not 0 <= frame < shape[0] or not (0 <= ci * cx < shape[1] and 0 <= cj * cy < shape[2]):
            raise ValueError(f"{where}: frame {frame} chunk ({ci}, {cj}) outside the array {shape}")
        key = f"{where}/c/{frame}/{ci}/{cj}" + "/0" * (len(shape) - 3)
        payload = get_object(self.store, key)
        if payload is None:
            return None
        try:
            block = decode_chunk(payload, dtype, chunks[1:], scratch=scratch)
        except (RuntimeError, ValueError) as exc:
            raise StoreError(f"damaged chunk in the store {self.store.url}: {key}: {exc}") from exc
        return block[: min(cx, shape[1] - ci * cx), : min(cy, shape[2] - cj * cy)]

    def read_frame(self, sequence_id: str, group, frame: int, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Whole frames of the named arrays (:meth:`read_tile` over the whole first axis)."""
        return {n: self.read_tile(sequence_id, group, frame, n, 0, self._layout(sequence_id, group, n)[0][1])
                for n in names}

    # -- lineage ------------------------------------------------------------------------------
    def frame_fingerprint(self, array_path: str, frame: int) -> str | None:
        """Fingerprint of one frame as stored (see :func:`carlaocc.catalog.zarrio.frame_fingerprint`);
        None when the array does not exist."""
        return frame_fingerprint(self.store, self.zarr_root, array_path, frame)

    def fingerprints(self, sequence_id: str, group, frame: int, names: tuple[str, ...]) -> dict[str, str]:
        """Lineage key -> fingerprint of one frame of each named array (the arrays' groups'
        metadata checked once for all of them: on an object store each check is a request)."""
        checked: dict[str, str | None] = {}
        return {self.output_key(sequence_id, group, n, frame):
                frame_fingerprint(self.store, self.zarr_root, self.array_path(sequence_id, group, n), frame, checked)
                for n in names}
