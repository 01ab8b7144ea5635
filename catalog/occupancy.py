"""Occupancy volumes in Zarr v3:
``occupancy.zarr/<sequence>/<voxel_size>/{semantic,instance,mask_camera,mask_lidar,flow,observed_bits}``.

Each array is ``(frame, x, y, z)`` (``flow`` has a trailing axis of 3 velocity components;
``observed_bits`` holds z packed eight voxels to a byte, ``(frame, x, y, ceil(Z / 8))``); a
chunk is one frame's ``chunk_edge x chunk_edge x Z`` column block, so a task that writes one whole
frame writes whole chunks and no two tasks ever touch the same chunk. Arrays are created by the
driver before any task runs (:meth:`OccupancyStore.create`) and carry the grid spec, voxel size,
origin, frame and taxonomy version in their attributes.

What every frame-indexed hierarchy shares (keep-or-replace creation, whole-chunk tile writes
encoded here rather than through zarr-python, all-zero chunks not stored, direct chunk reads,
fingerprints) is :class:`carlaocc.catalog.zarrstore.FrameArrayStore`; this module adds the
occupancy layout and attributes, the grid a sequence was voxelized on, the chunk bookkeeping
of a frame's x-tiles (which chunks voxel boxes or voxel indices reach: :meth:`~OccupancyStore.
chunks_of_boxes`, :meth:`~OccupancyStore.chunks_of_indices`) and the writers of sparse x-tiles,
which store the same chunks as a dense tile without copying or scanning its zeros: a tile
nonzero only inside voxel boxes (instances: :meth:`~OccupancyStore.write_boxes`) or only at
given voxels (flow: :meth:`~OccupancyStore.write_points`). Measured: one 0.05 m uint8 frame
through ``arr[frame] = data`` takes 2.1 s, through :meth:`~OccupancyStore.write_tile` 0.3 s.
"""

from __future__ import annotations

import threading

import numpy as np
import zarr

from carlaocc.catalog.store import OCCUPANCY_ZARR
from carlaocc.catalog.zarrio import parse_frame_key
from carlaocc.catalog.zarrstore import FrameArrayStore
from carlaocc.schemas.grid import GridSpec, voxel_size_key
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

# array name -> dtype, description, trailing axes (beyond frame, x, y, z)
OCCUPANCY_ARRAYS: dict[str, tuple[str, str, tuple[int, ...]]] = {
    "semantic": ("uint8", "semantic class id per voxel (0 = free), CarlaOcc 30-class taxonomy", ()),
    "instance": ("uint32", "instance id per voxel, unique within the sequence (0 = stuff or free)", ()),
    "mask_camera": ("uint8", "1 = observed by a camera of the rig: a pixel ray crosses or ends in the voxel "
                             "before the first occupied voxel (Occ3D semantics)", ()),
    "mask_lidar": ("uint8", "1 = observed by the LiDAR: a beam of the rig crosses or ends in the voxel before "
                            "the first occupied voxel (Occ3D semantics)", ()),
    "flow": ("float16", "velocity of the voxel's material point, m/s, world motion expressed in the LiDAR "
                        "frame's axes (x, y, z); 0 for free, stuff and static voxels", (3,)),
    "observed_bits": ("uint8", "mask_camera | mask_lidar (observed by any sensor of the rig) as bits packed along "
                               "z: voxel (x, y, z) is bit z % 8 of byte z // 8; np.unpackbits(a, axis=-1, count=Z, "
                               "bitorder='little') gives the uint8 mask; written with the masks for the quality "
                               "stage", ()),
}
# arrays whose last axis holds the z axis packed eight voxels to a byte (little bit order)
PACKED_Z = frozenset({"observed_bits"})


def packed_z(z: int) -> int:
    """Bytes along the last axis of a packed-z array (:data:`PACKED_Z`) of a grid ``z`` voxels high."""
    return -(-int(z) // 8)


def parse_output_key(key: str) -> tuple[str, int] | None:
    """``occupancy.zarr/<seq>/<voxel_size>/<name>[<frame>]`` -> (array path, frame); None otherwise
    (see :func:`carlaocc.catalog.zarrio.parse_frame_key` for the frame keys of any Zarr root)."""
    parsed = parse_frame_key(key)
    if parsed is None or parsed[0] != OCCUPANCY_ZARR:
        return None
    return parsed[1], parsed[2]


def _no_chunks(shape: tuple[int, ...], cx: int, cy: int) -> np.ndarray:
    """All-false chunk flags (x chunks, y chunks) of a tile of ``shape`` (X, Y, ...)."""
    return np.zeros((-(-shape[0] // cx), -(-shape[1] // cy)), dtype=bool)


class OccupancyStore(FrameArrayStore):
    """The occupancy Zarr hierarchy of a store: arrays addressed ``(sequence_id, grid, name)``."""

    zarr_root = OCCUPANCY_ZARR
    arrays = OCCUPANCY_ARRAYS
    kind = "occupancy arrays"
    # bits compress less at level 1 than bytes: 1.86 MiB a 0.05 m frame at 1, 1.06 at 3, for the
    # same encoding time on 50 MiB (docs/benchmarks.md)
    zstd_levels = {"observed_bits": 3}

    @staticmethod
    def array_path(sequence_id: str, grid: GridSpec, name: str) -> str:
        return f"{sequence_id}/{grid.key}/{name}"

    def create(self, sequence_id: str, grid: GridSpec, frame_count: int, chunk_edge: int,
               extra_attrs: dict | None = None, names: tuple[str, ...] | None = None) -> bool:
        """Create (or keep, when identical) the arrays of one sequence at one voxel size.

        An existing array with the same shape, dtype, chunks and attributes is kept with its
        data; one that differs (another region, frame count, taxonomy...) is replaced, and then
        every frame of it must be written again: returns True when an existing array was replaced.
        ``names`` (default: all of :data:`OCCUPANCY_ARRAYS`) selects the arrays; arrays left out
        that exist from an earlier configuration are deleted, so nothing stale stays readable.
        """
        X, Y, Z = grid.shape
        attrs = {
            **grid.attrs(),
            "dims": ["frame", "x", "y", "z"],
            "sequence_id": sequence_id,
            "taxonomy_version": TAXONOMY_VERSION,
            **(extra_attrs or {}),
        }
        names = tuple(OCCUPANCY_ARRAYS) if names is None else tuple(names)
        return self._create_arrays(sequence_id, grid, names, frame_count, (X, Y, Z),
                                   (min(chunk_edge, X), min(chunk_edge, Y), Z), attrs)

    def _array_layout(self, name, frame_shape, chunk_shape, dims):
        """The packed-z arrays (:data:`PACKED_Z`) hold ``ceil(Z / 8)`` bytes per column."""
        if name not in PACKED_Z:
            return super()._array_layout(name, frame_shape, chunk_shape, dims)
        return ((*frame_shape[:2], packed_z(frame_shape[2])), (*chunk_shape[:2], packed_z(chunk_shape[2])),
                [*(dims or ["frame", "x", "y", "z"])[:-1], "z_bytes"])

    def _stale_arrays(self, root: zarr.Group, sequence_id: str, grid: GridSpec, names: tuple[str, ...]) -> list[str]:
        """The occupancy arrays not in ``names`` that exist (an earlier configuration's)."""
        paths = (self.array_path(sequence_id, grid, n) for n in OCCUPANCY_ARRAYS if n not in names)
        return [p for p in paths if p in root]

    def stored_grid(self, sequence_id: str, voxel_size: float) -> GridSpec | None:
        """The grid a sequence was voxelized on at ``voxel_size`` (from the arrays' attributes,
        whatever the current config says), or None when it was not."""
        arr = self._node(f"{sequence_id}/{voxel_size_key(voxel_size)}/semantic")
        if not isinstance(arr, zarr.Array):
            return None
        return GridSpec.model_validate(dict(arr.attrs)["grid_spec"])

    def voxel_sizes(self, sequence_id: str) -> list[float]:
        """The voxel sizes (m) a sequence has occupancy at, ascending (from the hierarchy's groups)."""
        node = self._node(sequence_id)
        if not isinstance(node, zarr.Group):
            return []
        out = []
        for key in node.group_keys():
            try:
                size = float(key)
            except ValueError:
                continue
            if self.stored_grid(sequence_id, size) is not None:
                out.append(size)
        return sorted(out)

    def attrs(self, sequence_id: str, grid: GridSpec, name: str = "semantic") -> dict:
        """The attributes of one array (grid spec, frame, taxonomy version, rig LiDAR pose...)."""
        return super().attrs(sequence_id, grid, name)

    def read_frame(self, sequence_id: str, grid: GridSpec, frame: int,
                   names: tuple[str, ...] = ("semantic", "instance")) -> dict[str, np.ndarray]:
        """Whole frames of the named arrays (:meth:`read_tile` over the whole x range)."""
        return super().read_frame(sequence_id, grid, frame, names)

    # -- chunk bookkeeping of a frame's x-tiles ---------------------------------------------------
    def chunks_of_boxes(self, sequence_id: str, grid: GridSpec, name: str, things: np.ndarray,
                        shape: tuple[int, ...]) -> np.ndarray:
        """Chunk flags (x chunks, y chunks) of the chunks of an x-tile of ``shape`` (nx, Y, Z) of
        array ``name`` that the voxel boxes ``things`` reach (rows: instance, i0, i1, j0, j1, k0,
        k1, voxel index ranges within the tile, ends exclusive): where the tile can be nonzero,
        as ``candidates`` of :meth:`write_tile`. Empty boxes reach nothing."""
        cx, cy = self.chunk_edges(sequence_id, grid, name)
        flags = _no_chunks(shape, cx, cy)
        for _, i0, i1, j0, j1, k0, k1 in things:
            if i1 > i0 and j1 > j0 and k1 > k0:
                flags[i0 // cx:(i1 - 1) // cx + 1, j0 // cy:(j1 - 1) // cy + 1] = True
        return flags

    def chunks_of_indices(self, sequence_id: str, grid: GridSpec, name: str, flat: np.ndarray,
                          shape: tuple[int, ...]) -> np.ndarray:
        """Chunk flags (x chunks, y chunks) of the chunks of array ``name`` holding the C-order
        voxel indices ``flat`` of an x-tile of ``shape`` (nx, Y, Z), as ``candidates`` of
        :meth:`write_tile`."""
        cx, cy = self.chunk_edges(sequence_id, grid, name)
        flags = _no_chunks(shape, cx, cy)
        flags[flat // (shape[1] * shape[2]) // cx, (flat // shape[2]) % shape[1] // cy] = True
        return flags

    # -- sparse x-tiles: chunks assembled from where the data is ------------------------------------
    def write_boxes(self, sequence_id: str, grid: GridSpec, frame: int, name: str, data: np.ndarray, x0: int,
                    boxes: np.ndarray) -> None:
        """Write an x-tile ``data`` (nx, Y, Z) of array ``name`` whose nonzero values all lie inside
        the voxel boxes ``boxes`` (rows: instance, i0, i1, j0, j1, k0, k1 within the tile, ends
        exclusive, as :meth:`chunks_of_boxes` takes them). Stores exactly the chunks
        :meth:`~carlaocc.catalog.zarrstore.FrameArrayStore.write_tile` stores for ``data`` with
        those candidates, but each chunk is assembled from the boxes' parts in a per-thread
        chunk buffer kept zero, so the chunk's zeros are neither copied out of the tile nor
        scanned (a 0.05 m instance chunk is 16 MiB around a few cars)."""
        shape, chunks, dtype = self._layout(sequence_id, grid, name)
        where = f"{self._where(self.array_path(sequence_id, grid, name))} frame {frame}"
        data = np.asarray(data)
        if data.ndim != len(shape) - 1 or data.shape[1:] != shape[2:]:
            raise ValueError(f"{where}: tile shape {data.shape} does not match the array's {shape[1:]} beyond x")
        cx, cy = chunks[1], chunks[2]
        boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 7)
        boxes = boxes[(boxes[:, 2] > boxes[:, 1]) & (boxes[:, 4] > boxes[:, 3]) & (boxes[:, 6] > boxes[:, 5])]
        buf = _zero_chunk(chunks[1:], dtype.newbyteorder("<"))
        bits = np.dtype(f"u{dtype.itemsize}")  # nonzero bitwise (-0.0 is data), as write_tile
        written: list[tuple[slice, ...]] = []  # the parts of buf to zero again

        def clean() -> None:
            for region in written:
                buf[region] = 0
            written.clear()

        def block(ci: int, cj: int) -> np.ndarray | None:
            clean()  # the previous chunk is encoded by now
            xa, ya = ci * cx - x0, cj * cy
            for _, i0, i1, j0, j1, k0, k1 in boxes:
                # the box's part inside this chunk, in tile and in chunk coordinates
                a, b, c, d = max(i0, xa), min(i1, xa + cx), max(j0, ya), min(j1, ya + cy)
                if a < b and c < d:
                    region = (slice(a - xa, b - xa), slice(c - ya, d - ya), slice(k0, k1))
                    buf[region] = data[a:b, c:d, k0:k1]
                    written.append(region)
            return buf if any(buf[r].view(bits).any() for r in written) else None

        try:
            self.write_chunks(sequence_id, grid, frame, name, x0, data.shape[0], block)
        finally:
            clean()

    def write_points(self, sequence_id: str, grid: GridSpec, frame: int, name: str, x0: int, nx: int,
                     flat: np.ndarray, values: np.ndarray) -> None:
        """Write the x-tile ``[x0, x0 + nx)`` of array ``name`` as zero except at the C-order voxel
        indices ``flat`` of the tile (nx, Y, Z), which hold ``values`` (one row each, the array's
        trailing axes; distinct indices). Stores exactly the chunks
        :meth:`~carlaocc.catalog.zarrstore.FrameArrayStore.write_tile` stores for the dense tile
        (a chunk whose values are all zero bitwise is not stored), without the dense tile: each
        chunk's values are scattered into a per-thread chunk buffer kept zero (a 0.05 m flow tile
        is 200 MiB for a few hundred kB of flow)."""
        shape, chunks, dtype = self._layout(sequence_id, grid, name)
        where = f"{self._where(self.array_path(sequence_id, grid, name))} frame {frame}"
        Y, Z, trailing = shape[2], shape[3], tuple(shape[4:])
        cx, cy = chunks[1], chunks[2]
        flat = np.asarray(flat, dtype=np.int64).reshape(-1)
        values = np.asarray(values)
        if values.shape != (len(flat), *trailing):
            raise ValueError(f"{where}: {values.shape} values for {len(flat)} voxels of {trailing} components")
        if len(flat) and (flat.min() < 0 or flat.max() >= nx * Y * Z):
            raise ValueError(f"{where}: voxel indices outside the tile ({nx}, {Y}, {Z})")
        # 1. each voxel's chunk (within the tile) and its index inside the chunk
        i, rest = np.divmod(flat, Y * Z)
        j, k = np.divmod(rest, Z)
        ncy = -(-Y // cy)
        chunk = (i // cx) * ncy + j // cy
        local = ((i % cx) * cy + j % cy) * Z + k
        # 2. voxels grouped by chunk (stable: the order within a chunk is kept)
        order = np.argsort(chunk, kind="stable")
        starts = np.searchsorted(chunk[order], np.arange(-(-nx // cx) * ncy + 1))
        buf = _zero_chunk(chunks[1:], dtype.newbyteorder("<"))
        cells = buf.reshape(cx * cy * Z, *trailing)
        bits = np.dtype(f"u{dtype.itemsize}")
        written: list[np.ndarray] = []

        def clean() -> None:
            for idx in written:
                cells[idx] = 0
            written.clear()

        def block(ci: int, cj: int) -> np.ndarray | None:
            clean()
            c = (ci - x0 // cx) * ncy + cj
            sel = order[starts[c]:starts[c + 1]]
            if not len(sel):
                return None
            idx = local[sel]
            cells[idx] = values[sel]
            written.append(idx)
            return buf if cells[idx].view(bits).any() else None  # as stored (cast to the array's dtype)

        try:
            self.write_chunks(sequence_id, grid, frame, name, x0, nx, block)
        finally:
            clean()


_BUFFERS = threading.local()  # per thread: (chunk shape, dtype) -> a chunk buffer kept all zero


def _zero_chunk(shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """This thread's all-zero chunk buffer of ``shape`` and ``dtype``: whoever writes into it
    zeroes what it wrote before returning (allocated once: fresh pages cost more than the data)."""
    cache = getattr(_BUFFERS, "chunks", None)
    if cache is None:
        cache = _BUFFERS.chunks = {}
    key = (tuple(shape), np.dtype(dtype).str)
    if key not in cache:
        cache[key] = np.zeros(shape, dtype)
    return cache[key]
