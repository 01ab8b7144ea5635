"""Camera maps in Zarr v3 (``sensors.zarr/<sequence>/<camera>/<map>``) and LiDAR points in
Parquet (``lidar/<sequence>/<frame:06d>.parquet``): one place per format, load/save/exists.

A camera map is an array ``(frame, v, u)`` (``normal`` has a trailing axis of 3 components) with
one chunk per image, so a task that writes one frame of one camera writes whole chunks and no two
tasks touch the same chunk. The arrays are created by the driver before tasks run
(:meth:`SensorStore.create`) and carry the camera, sequence, taxonomy version and whatever the
caller adds (intrinsics ``K``, ``camera_to_ego``) in their attributes. Images are encoded here
(:mod:`catalog.zarrio`) and stored as one object each; an all-zero image is not stored (its
chunk is removed), as zarr does with ``write_empty_chunks=False``. Reads go through zarr-python.

A LiDAR frame is one Parquet file of points in the LiDAR frame (x forward, y left, z up, metres),
written atomically with :meth:`Store.write_bytes`.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import zarr
from zarr.codecs import ZstdCodec

from carlaocc.catalog.parquet import table_bytes
from carlaocc.catalog.store import LIDAR_DIR, SENSORS_ZARR, Store, StoreError
from carlaocc.catalog.zarrio import ZSTD_LEVEL, encode_chunk, frame_fingerprint, put_object, remove_object, zarr_store
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

_RAW = "as the simulator delivers it (before rectification): "
_DEPTH = ("planar depth along the camera's optical axis (z of the OpenCV camera frame), metres; "
          "0 = no surface within range (sky)")
_SEMANTIC = "semantic class id of the first visible surface, CarlaOcc 30-class taxonomy; 11 (Sky) where no surface"
_INSTANCE = "instance id of the first visible surface (0 = stuff or no surface)"

# map name -> dtype, description, trailing axes (beyond frame, v, u)
SENSOR_MAPS: dict[str, tuple[str, str, tuple[int, ...]]] = {
    "depth": ("float32", _DEPTH, ()),
    "semantic": ("uint8", _SEMANTIC, ()),
    "instance": ("uint32", _INSTANCE, ()),
    "normal": ("float16", "unit surface normal in the OpenCV camera frame (x right, y down, z forward), from "
                          "the rectified depth by D2NT; 0 where depth is 0", (3,)),
    "depth_raw": ("float32", _RAW + _DEPTH, ()),
    "semantic_raw": ("uint8", _RAW + _SEMANTIC, ()),
    "instance_raw": ("uint32", _RAW + _INSTANCE, ()),
}
CAMERA_MAPS = ("depth", "semantic", "instance", "normal")

# column -> dtype, description
LIDAR_COLUMNS: dict[str, tuple[str, str]] = {
    "x": ("float32", "metres, LiDAR frame (x forward, y left, z up)"),
    "y": ("float32", "metres, LiDAR frame (x forward, y left, z up)"),
    "z": ("float32", "metres, LiDAR frame (x forward, y left, z up)"),
    "distance": ("float32", "metres from the LiDAR origin"),
    "semantic": ("uint8", "semantic class id of the hit surface, CarlaOcc 30-class taxonomy"),
    "instance": ("uint32", "instance id of the hit surface (0 = stuff)"),
    "channel": ("uint8", "beam index, 0 = top beam"),
}
LIDAR_FRAME_AXES = "lidar: x forward, y left, z up"
_FINITE = ("x", "y", "z", "distance")
_LIDAR_META = b"carlaocc.lidar"


def _cast(data: np.ndarray, dtype: str, what: str) -> np.ndarray:
    """``data`` as ``dtype``; ValueError naming ``what`` when the values do not fit (floats into an
    integer map, integers outside its range, non-numeric data)."""
    data = np.asarray(data)
    target = np.dtype(dtype)
    if target.kind in "ui":
        if data.dtype.kind not in "uib":
            raise ValueError(f"{what}: {data.dtype} data cannot be stored as {target}")
        if data.size and data.dtype.kind != "b":
            info = np.iinfo(target)
            lo, hi = data.min(), data.max()
            if lo < info.min or hi > info.max:
                raise ValueError(f"{what}: values [{lo}, {hi}] outside the {target} range")
    elif data.dtype.kind not in "fiu":
        raise ValueError(f"{what}: {data.dtype} data cannot be stored as {target}")
    return data.astype(target, copy=False)


class SensorStore:
    """``sensors.zarr/<seq>/<camera>/<name>``: arrays (frame, height, width[, 3]), one chunk per image."""

    def __init__(self, store: Store):
        self.store = store

    def _root(self, mode: str) -> zarr.Group:
        return zarr.open_group(store=zarr_store(self.store, SENSORS_ZARR), mode=mode)

    def _node(self, path: str):
        """The node at ``path`` of the hierarchy, or None when it (or the hierarchy) is missing."""
        try:
            return self._root("r")[path]
        except (KeyError, FileNotFoundError, zarr.errors.GroupNotFoundError):
            return None

    @staticmethod
    def array_path(sequence_id: str, camera: str, name: str) -> str:
        return f"{sequence_id}/{camera}/{name}"

    def output_key(self, sequence_id: str, camera: str, name: str, frame: int) -> str:
        """Lineage key of one image: ``sensors.zarr/<seq>/<camera>/<name>[<frame>]``."""
        return f"{SENSORS_ZARR}/{self.array_path(sequence_id, camera, name)}[{frame}]"

    def create(self, sequence_id: str, camera: str, width: int, height: int, frame_count: int,
               names: tuple[str, ...], extra_attrs: dict | None = None, keep_others: bool = False) -> bool:
        """Create (or keep, when identical) the map arrays of one camera of one sequence.

        An existing array with the same shape, dtype, chunks and attributes is kept with its data;
        one that differs (another image size, frame count, intrinsics...) is replaced, and then
        every frame of it must be written again: returns True when an existing array was replaced.
        Arrays of the camera not in ``names`` that exist are deleted, so nothing stale stays
        readable, unless ``keep_others`` (the recorded path: a recorder's ``*_raw`` arrays are its
        input and are never touched). ``extra_attrs`` must be
        JSON-serialisable (intrinsics ``K`` and ``camera_to_ego`` as nested lists).
        """
        names = tuple(names)
        unknown = set(names) - set(SENSOR_MAPS)
        if unknown:
            raise ValueError(f"unknown camera maps {sorted(unknown)}; known: {', '.join(SENSOR_MAPS)}")
        replaced = False
        self.__dict__.pop("_layouts", None)  # arrays may be recreated with another layout
        root = self._root("a")
        group = f"{sequence_id}/{camera}"
        if not keep_others and group in root and isinstance(root[group], zarr.Group):
            for stale in sorted(set(root[group].array_keys()) - set(names)):
                del root[f"{group}/{stale}"]
        # attributes as stored (JSON): tuples become lists, so an identical call compares equal
        attrs = json.loads(json.dumps({
            "dims": ["frame", "v", "u"],
            "sequence_id": sequence_id,
            "camera": camera,
            "taxonomy_version": TAXONOMY_VERSION,
            **(extra_attrs or {}),
        }))
        for name in names:
            dtype, description, trailing = SENSOR_MAPS[name]
            path = self.array_path(sequence_id, camera, name)
            shape = (frame_count, height, width, *trailing)
            chunks = (1, height, width, *trailing)
            want = {**attrs, "description": description}
            if trailing:
                want["dims"] = [*attrs["dims"], "component"]
            if path in root:
                arr = root[path]
                if (isinstance(arr, zarr.Array) and arr.shape == shape and arr.chunks == chunks
                        and str(arr.dtype) == dtype and dict(arr.attrs) == want):
                    continue
                replaced = True
            root.create_array(path, shape=shape, chunks=chunks, dtype=dtype, fill_value=0,
                              compressors=ZstdCodec(level=ZSTD_LEVEL), overwrite=True, attributes=want)
        return replaced

    def _layout(self, sequence_id: str, camera: str, name: str) -> tuple[tuple, np.dtype]:
        """(shape, dtype) of an array, read once from its metadata per store object."""
        cache = self.__dict__.setdefault("_layouts", {})
        path = self.array_path(sequence_id, camera, name)
        if path not in cache:
            arr = self._node(path)
            if not isinstance(arr, zarr.Array):
                raise ValueError(f"{SENSORS_ZARR}/{path} does not exist (create it before writing)")
            cache[path] = (tuple(arr.shape), np.dtype(arr.dtype))
        return cache[path]

    def _chunk_key(self, sequence_id: str, camera: str, name: str, frame: int, ndim: int) -> str:
        """Store-relative key of the one chunk of an image (chunk grid ``(frame, 0, 0[, 0])``)."""
        return f"{SENSORS_ZARR}/{self.array_path(sequence_id, camera, name)}/c/{frame}" + "/0" * (ndim - 1)

    def write_image(self, sequence_id: str, camera: str, frame: int, name: str, data: np.ndarray) -> None:
        """Write one image (height, width[, 3]) of one map as its whole chunk, atomically; an
        all-zero image (bitwise: -0.0 counts as data) removes the chunk instead."""
        what = f"{sequence_id}/{camera}/{name} frame {frame}"
        shape, dtype = self._layout(sequence_id, camera, name)
        if not 0 <= frame < shape[0]:
            raise ValueError(f"{what}: frame outside [0, {shape[0]})")
        data = np.asarray(data)
        if data.shape != shape[1:]:
            raise ValueError(f"{what}: image shape {data.shape} does not match the array's {shape[1:]}")
        block = np.ascontiguousarray(_cast(data, dtype.name, what), dtype=dtype.newbyteorder("<"))
        key = self._chunk_key(sequence_id, camera, name, frame, len(shape))
        if not block.reshape(-1).view(np.uint8).any():
            remove_object(self.store, key)
            return
        put_object(self.store, key, encode_chunk(block, dtype))

    def open(self, sequence_id: str, camera: str, name: str) -> zarr.Array:
        """The zarr array of one map (read-only use); StoreError naming it when missing."""
        path = self.array_path(sequence_id, camera, name)
        arr = self._node(path)
        if not isinstance(arr, zarr.Array):
            raise StoreError(f"missing in the store {self.store.url}: {SENSORS_ZARR}/{path}")
        return arr

    def read_image(self, sequence_id: str, camera: str, frame: int, name: str) -> np.ndarray:
        """One image (height, width[, 3]) of one map, through zarr-python (zeros where not written)."""
        path = self.array_path(sequence_id, camera, name)
        arr = self._node(path)
        if not isinstance(arr, zarr.Array):
            raise StoreError(f"missing in the store {self.store.url}: {SENSORS_ZARR}/{path}")
        return arr[frame]

    def exists(self, sequence_id: str, camera: str, name: str, frame: int | None = None) -> bool:
        """The array exists; with ``frame``: also within its frame count and the image's chunk is
        stored. An image written all zero has no chunk, so it does not count as existing."""
        arr = self._node(self.array_path(sequence_id, camera, name))
        if not isinstance(arr, zarr.Array):
            return False
        if frame is None:
            return True
        return (0 <= frame < arr.shape[0]
                and self.store.exists(self._chunk_key(sequence_id, camera, name, frame, arr.ndim)))

    def cameras(self, sequence_id: str) -> list[str]:
        """Camera groups of a sequence, sorted."""
        group = self._node(sequence_id)
        return sorted(group.group_keys()) if isinstance(group, zarr.Group) else []

    def names(self, sequence_id: str, camera: str) -> list[str]:
        """Map arrays of one camera, sorted."""
        group = self._node(f"{sequence_id}/{camera}")
        return sorted(group.array_keys()) if isinstance(group, zarr.Group) else []

    def attrs(self, sequence_id: str, camera: str, name: str) -> dict:
        """The attributes of one array (dims, camera, taxonomy version, intrinsics...)."""
        path = self.array_path(sequence_id, camera, name)
        arr = self._node(path)
        if arr is None:
            raise StoreError(f"missing in the store {self.store.url}: {SENSORS_ZARR}/{path}")
        return dict(arr.attrs)

    def fingerprints(self, sequence_id: str, camera: str, frame: int, names: tuple[str, ...]) -> dict[str, str]:
        """Lineage key -> fingerprint of one frame of each named map (see
        :func:`catalog.zarrio.frame_fingerprint`)."""
        return {self.output_key(sequence_id, camera, n, frame):
                frame_fingerprint(self.store, SENSORS_ZARR, self.array_path(sequence_id, camera, n), frame)
                for n in names}


class LidarStore:
    """``lidar/<seq>/<frame:06d>.parquet``: one file per frame, points in the LiDAR frame
    (x forward, y left, z up, metres), columns :data:`LIDAR_COLUMNS`."""

    def __init__(self, store: Store):
        self.store = store

    @staticmethod
    def path(sequence_id: str, frame: int) -> str:
        return f"{LIDAR_DIR}/{sequence_id}/{frame:06d}.parquet"

    @staticmethod
    def _schema(metadata: dict) -> pa.Schema:
        """Arrow schema of a frame's file: each field's description in its field metadata, the
        frame's metadata as JSON in the schema metadata."""
        fields = [pa.field(c, pa.from_numpy_dtype(np.dtype(d)), nullable=False,
                           metadata={b"description": desc.encode()}) for c, (d, desc) in LIDAR_COLUMNS.items()]
        return pa.schema(fields, metadata={_LIDAR_META: json.dumps(metadata, sort_keys=True).encode()})

    def save(self, sequence_id: str, frame: int, points: dict[str, np.ndarray],
             metadata: dict | None = None) -> str:
        """Atomically write one frame's points; returns the file's fingerprint. ``points`` holds
        exactly the :data:`LIDAR_COLUMNS`, 1-D and of equal length, finite x, y, z, distance;
        ``metadata`` (JSON-serialisable) is added to the file's schema metadata."""
        what = f"lidar {sequence_id} frame {frame}"
        missing, extra = set(LIDAR_COLUMNS) - set(points), set(points) - set(LIDAR_COLUMNS)
        if missing or extra:
            raise ValueError(f"{what}: missing columns {sorted(missing)}, unknown columns {sorted(extra)}; "
                             f"expected {', '.join(LIDAR_COLUMNS)}")
        columns, n = {}, None
        for c, (dtype, _) in LIDAR_COLUMNS.items():
            values = np.asarray(points[c])
            if values.ndim != 1:
                raise ValueError(f"{what}: column {c} has shape {values.shape}, expected 1-D")
            if n is None:
                n = len(values)
            elif len(values) != n:
                raise ValueError(f"{what}: column {c} has {len(values)} points, column x has {n}")
            values = _cast(values, dtype, f"{what}: column {c}")
            if c in _FINITE and not np.isfinite(values).all():
                raise ValueError(f"{what}: column {c} has non-finite values")
            columns[c] = values
        meta = {"sequence_id": sequence_id, "frame": frame, "frame_axes": LIDAR_FRAME_AXES, **(metadata or {})}
        schema = self._schema(meta)
        table = pa.Table.from_arrays([pa.array(columns[f.name], type=f.type) for f in schema], schema=schema)
        return self.store.write_bytes(self.path(sequence_id, frame), table_bytes(table))

    def _file(self, sequence_id: str, frame: int) -> io.BytesIO:
        return io.BytesIO(self.store.read_bytes(self.path(sequence_id, frame)))

    def load(self, sequence_id: str, frame: int) -> dict[str, np.ndarray]:
        """One frame's points: column -> numpy array of the column's dtype. StoreError naming the
        file when it is missing or lacks a column."""
        table = pq.read_table(self._file(sequence_id, frame))
        missing = [c for c in LIDAR_COLUMNS if c not in table.column_names]
        if missing:
            raise StoreError(f"{self.store.url}: {self.path(sequence_id, frame)} lacks columns {missing}")
        return {c: table.column(c).to_numpy().astype(d, copy=False) for c, (d, _) in LIDAR_COLUMNS.items()}

    def metadata(self, sequence_id: str, frame: int) -> dict:
        """The frame's metadata (sequence_id, frame, frame_axes and what the writer added)."""
        meta = pq.read_schema(self._file(sequence_id, frame)).metadata or {}
        return json.loads(meta[_LIDAR_META]) if _LIDAR_META in meta else {}

    def exists(self, sequence_id: str, frame: int) -> bool:
        return self.store.exists(self.path(sequence_id, frame))

    def frames(self, sequence_id: str) -> list[int]:
        """Frame indices stored for a sequence, sorted."""
        out = []
        for p in self.store.glob(f"{LIDAR_DIR}/{sequence_id}", ".parquet"):
            head, stem = p.rsplit("/", 1)
            if head == f"{LIDAR_DIR}/{sequence_id}" and stem[:-len(".parquet")].isdigit():
                out.append(int(stem[:-len(".parquet")]))
        return sorted(out)
