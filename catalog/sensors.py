"""Camera maps in Zarr v3 (``sensors.zarr/<sequence>/<camera>/<map>``) and LiDAR points in
Parquet (``lidar/<sequence>/<frame:06d>.parquet``): one place per format, load/save/exists.

A camera map is an array ``(frame, v, u)`` (``normal`` has a trailing axis of 3 components) with
one chunk per image, so a task that writes one frame of one camera writes whole chunks and no two
tasks touch the same chunk. The arrays are created by the driver before tasks run
(:meth:`SensorStore.create`) and carry the camera, sequence, taxonomy version and whatever the
caller adds (intrinsics ``K``, ``camera_to_ego``) in their attributes. Creating, writing (each
image encoded as one object; an all-zero image is not stored, its chunk removed, as zarr does with
``write_empty_chunks=False``), lineage keys and fingerprints are those of every frame-indexed
hierarchy (:class:`carlaocc.catalog.zarrstore.FrameArrayStore`); images are read through
zarr-python, so a recorder may write its ``*_raw`` arrays with any codec.

A LiDAR frame is one Parquet file of points in the LiDAR frame (x forward, y left, z up, metres),
written atomically with :meth:`Store.write_bytes`: our ray-cast scans in ``lidar/``
(:class:`LidarStore`), a recording's own scans in ``lidar_recorded/`` (:class:`RecordedLidarStore`).
"""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import zarr

from carlaocc.catalog.parquet import table_bytes
from carlaocc.catalog.store import LIDAR_DIR, LIDAR_RECORDED_DIR, SENSORS_ZARR, Store, StoreError
from carlaocc.catalog.zarrstore import FrameArrayStore
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
    "rgb": ("uint8", "colour image, 8-bit RGB: a recording's as the recorder saved it (the CarlaOcc saver's x1.2 "
                     "gain kept), else shaded from the frame's scene (base colours, sun and cast shadows, ambient, sky)",
            (3,)),
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
# a recording's scans (CARLA's ray_cast and ray_cast_semantic LiDARs as the CarlaOcc saver writes
# them, lidar/ and semantic_lidar/ PLY) and our range along each recorded beam
_RECORDED = "as recorded; NaN / the not-recorded value in the other scan"
RECORDED_LIDAR_COLUMNS: dict[str, tuple[str, str]] = {
    **{name: LIDAR_COLUMNS[name] for name in ("x", "y", "z", "distance")},  # the points, as our scans hold them
    "scan": ("uint8", "0: the recording's lidar/ scan (CARLA ray_cast), 1: its semantic_lidar/ scan (ray_cast_semantic)"),
    "intensity": ("float32", "CARLA's intensity (scan 0); " + _RECORDED),
    "cos_angle": ("float32", "cosine of the incidence angle (scan 1); " + _RECORDED),
    "object_index": ("int64", "CARLA actor id of the hit object (scan 1; 0 = none); -1 in scan 0"),
    "semantic": ("uint8", "CARLA's semantic tag of the hit (scan 1; the CarlaOcc 30-class ids); 255 in scan 0"),
    "raycast_distance": ("float32", "ours: the range along this point's beam through the frame's scene mesh, "
                                    "metres; inf where our scene has nothing along the beam"),
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


class SensorStore(FrameArrayStore):
    """``sensors.zarr/<seq>/<camera>/<name>``: arrays (frame, height, width[, 3]), one chunk per
    image, addressed ``(sequence_id, camera, name)``."""

    zarr_root = SENSORS_ZARR
    arrays = SENSOR_MAPS
    kind = "camera maps"

    @staticmethod
    def array_path(sequence_id: str, camera: str, name: str) -> str:
        return f"{sequence_id}/{camera}/{name}"

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
        # attributes as stored (JSON): tuples become lists, so an identical call compares equal
        attrs = json.loads(json.dumps({
            "dims": ["frame", "v", "u"],
            "sequence_id": sequence_id,
            "camera": camera,
            "taxonomy_version": TAXONOMY_VERSION,
            **(extra_attrs or {}),
        }))
        return self._create_arrays(sequence_id, camera, names, frame_count, (height, width), (height, width),
                                   attrs, drop_others=not keep_others)

    def _values(self, data: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
        """``data`` cast to the map's dtype; ValueError naming the image when the values do not fit."""
        return _cast(data, dtype.name, what)

    def _chunk_key(self, sequence_id: str, camera: str, name: str, frame: int, ndim: int) -> str:
        """Store-relative key of the one chunk of an image (chunk grid ``(frame, 0, 0[, 0])``)."""
        return f"{SENSORS_ZARR}/{self.array_path(sequence_id, camera, name)}/c/{frame}" + "/0" * (ndim - 1)

    def write_image(self, sequence_id: str, camera: str, frame: int, name: str, data: np.ndarray) -> None:
        """Write one image (height, width[, 3]) of one map as its whole chunk, atomically; an
        all-zero image (bitwise: -0.0 counts as data) removes the chunk instead."""
        shape = self._layout(sequence_id, camera, name)[0]
        data = np.asarray(data)
        if data.shape != shape[1:]:
            raise ValueError(f"{sequence_id}/{camera}/{name} frame {frame}: image shape {data.shape} "
                             f"does not match the array's {shape[1:]}")
        self.write_tile(sequence_id, camera, frame, name, data, 0)

    def read_image(self, sequence_id: str, camera: str, frame: int, name: str) -> np.ndarray:
        """One image (height, width[, 3]) of one map, through zarr-python (zeros where not written:
        a recorder may write its ``*_raw`` arrays with other codecs); StoreError naming the array
        when it is missing or its chunk cannot be decoded."""
        arr = self.open(sequence_id, camera, name)
        try:
            return arr[frame]
        except (RuntimeError, ValueError) as exc:  # a damaged chunk
            path = self.array_path(sequence_id, camera, name)
            raise StoreError(f"damaged in the store {self.store.url}: {SENSORS_ZARR}/{path} frame {frame}: "
                             f"{exc}") from exc

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


class LidarStore:
    """``lidar/<seq>/<frame:06d>.parquet``: one file per frame, points in the LiDAR frame
    (x forward, y left, z up, metres), columns :data:`LIDAR_COLUMNS`."""

    DIR = LIDAR_DIR
    COLUMNS = LIDAR_COLUMNS

    def __init__(self, store: Store):
        self.store = store

    @classmethod
    def path(cls, sequence_id: str, frame: int) -> str:
        return f"{cls.DIR}/{sequence_id}/{frame:06d}.parquet"

    @classmethod
    def _schema(cls, metadata: dict) -> pa.Schema:
        """Arrow schema of a frame's file: each field's description in its field metadata, the
        frame's metadata as JSON in the schema metadata."""
        fields = [pa.field(c, pa.from_numpy_dtype(np.dtype(d)), nullable=False,
                           metadata={b"description": desc.encode()}) for c, (d, desc) in cls.COLUMNS.items()]
        return pa.schema(fields, metadata={_LIDAR_META: json.dumps(metadata, sort_keys=True).encode()})

    def save(self, sequence_id: str, frame: int, points: dict[str, np.ndarray],
             metadata: dict | None = None) -> str:
        """Atomically write one frame's points; returns the file's fingerprint. ``points`` holds
        exactly the store's ``COLUMNS`` (:data:`LIDAR_COLUMNS`, :data:`RECORDED_LIDAR_COLUMNS`), 1-D and of equal length, finite x, y, z, distance;
        ``metadata`` (JSON-serialisable) is added to the file's schema metadata."""
        what = f"lidar {sequence_id} frame {frame}"
        missing, extra = set(self.COLUMNS) - set(points), set(points) - set(self.COLUMNS)
        if missing or extra:
            raise ValueError(f"{what}: missing columns {sorted(missing)}, unknown columns {sorted(extra)}; "
                             f"expected {', '.join(self.COLUMNS)}")
        columns, n = {}, None
        for c, (dtype, _) in self.COLUMNS.items():
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
        missing = [c for c in self.COLUMNS if c not in table.column_names]
        if missing:
            raise StoreError(f"{self.store.url}: {self.path(sequence_id, frame)} lacks columns {missing}")
        return {c: table.column(c).to_numpy().astype(d, copy=False) for c, (d, _) in self.COLUMNS.items()}

    def metadata(self, sequence_id: str, frame: int) -> dict:
        """The frame's metadata (sequence_id, frame, frame_axes and what the writer added)."""
        meta = pq.read_schema(self._file(sequence_id, frame)).metadata or {}
        return json.loads(meta[_LIDAR_META]) if _LIDAR_META in meta else {}

    def exists(self, sequence_id: str, frame: int) -> bool:
        return self.store.exists(self.path(sequence_id, frame))

    def frames(self, sequence_id: str) -> list[int]:
        """Frame indices stored for a sequence, sorted."""
        out = []
        for p in self.store.glob(f"{self.DIR}/{sequence_id}", ".parquet"):
            head, stem = p.rsplit("/", 1)
            if head == f"{self.DIR}/{sequence_id}" and stem[:-len(".parquet")].isdigit():
                out.append(int(stem[:-len(".parquet")]))
        return sorted(out)


class RecordedLidarStore(LidarStore):
    """``lidar_recorded/<seq>/<frame:06d>.parquet``: a recorded frame's own LiDAR scans (both of
    the recording's scans, told apart by ``scan``), points in the LiDAR frame (x forward, y left,
    z up, metres), with our range along each point's beam; columns :data:`RECORDED_LIDAR_COLUMNS`."""

    DIR = LIDAR_RECORDED_DIR
    COLUMNS = RECORDED_LIDAR_COLUMNS
