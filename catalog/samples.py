"""A built root's frames as samples: the store reading behind the training loader
(:class:`carlaocc.data.CarlaOccDataset`, whose docstring lists the keys; boxes are its own) and the exports.

:class:`FrameSamples` indexes the (sequence, frame) pairs of a root at one voxel size and reads
one frame's occupancy (sparse, dense or a crop, chunk by chunk), camera images and maps, LiDAR
points, and its actors' rows (:meth:`FrameSamples.actor_rows`: world-frame boxes, turned into the LiDAR frame by
:func:`carlaocc.stages.geometry.boxes_in_frame`). It holds the root's URL, never an open
store, so it pickles to worker processes.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sensors import LidarStore, SensorStore
from carlaocc.catalog.splits import SPLIT_NAMES, SplitStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.records import ActorStateRecord, FrameRecord, SequenceRecord

OCCUPANCY_MODES = ("sparse", "dense", "crop", "none")
DENSE_LIMIT = 64 * 2**20
"""Voxels above which ``occupancy="dense"`` (or a crop) is refused (a 0.2 m default grid has 6.4 M; 0.05 m, 409 M)."""
CAMERA_MAPS = ("depth", "semantic", "instance", "normal")
CAMERA_MAP_PREFIX = "cam_"
"""A camera map ``m`` is the sample key ``cam_<m>`` (``cam_semantic`` ...): the 3D grids own the bare names."""
OCC_ARRAYS = ("semantic", "instance", "flow", "mask_camera", "mask_lidar")
"""The stored occupancy arrays a sample carries (dense / crop under these names, sparse as ``occ`` and ``occ_<name>``)."""
_CACHE = 256  # sequences whose frames and actors tables a worker keeps (a few hundred KB each)


class DatasetError(ValueError):
    """The root, split, voxel size or an option cannot give the asked samples; the message says why."""


def check_options(occupancy: str, crop, camera_maps: Sequence[str], split: str | None, voxel_size,
                  sequences) -> list[str] | None:
    """The sample options every reader takes, checked (:class:`DatasetError` saying what is wrong);
    returns ``sequences`` as a list (one id may be given as a str)."""
    if occupancy not in OCCUPANCY_MODES:
        raise DatasetError(f"occupancy={occupancy!r}: one of {', '.join(OCCUPANCY_MODES)}")
    if (occupancy == "crop") != (crop is not None):
        raise DatasetError("occupancy='crop' takes crop=((x0, y0, z0), (x1, y1, z1)) in metres, and crop "
                           "needs occupancy='crop'")
    bad = [m for m in camera_maps if m not in CAMERA_MAPS]
    if bad:
        raise DatasetError(f"camera_maps {bad}: known maps are {', '.join(CAMERA_MAPS)}")
    if split is not None and split not in SPLIT_NAMES:
        raise DatasetError(f"split={split!r}: one of {', '.join(SPLIT_NAMES)} (or None for all)")
    if voxel_size is not None and not (isinstance(voxel_size, (int, float)) and voxel_size > 0):
        raise DatasetError(f"voxel_size={voxel_size!r}: a positive size in metres (or None for the finest built)")
    if isinstance(sequences, str):
        sequences = [sequences]
    if crop is not None:
        try:
            lo_, hi_ = (np.asarray(c, dtype=float) for c in crop)
            ok = lo_.shape == hi_.shape == (3,) and bool(np.all(np.isfinite(lo_) & np.isfinite(hi_) & (hi_ > lo_)))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise DatasetError(f"crop={crop!r}: ((x0, y0, z0), (x1, y1, z1)) in metres with x1 > x0, y1 > y0, z1 > z0")
    return None if sequences is None else list(sequences)


class FrameSamples:
    """Frames of a built carlaocc root as samples, read from the store: the index of (sequence,
    frame) pairs at one voxel size, and one frame's arrays on demand. The options and the keys are
    those of :class:`carlaocc.data.CarlaOccDataset` (its docstring), but the boxes: ``boxes``
    only records whether the caller wants them, and :meth:`actor_rows` gives their rows."""

    def __init__(self, root: str = "data", split: str | None = None, voxel_size: float | None = None,
                 occupancy: str = "sparse", crop: Sequence[Sequence[float]] | None = None, cameras: bool = True,
                 camera_maps: Sequence[str] = (), lidar: bool = True, boxes: bool = True,
                 sequences: Sequence[str] | None = None, dense_limit: int = DENSE_LIMIT) -> None:

        sequences = check_options(occupancy, crop, camera_maps, split, voxel_size, sequences)
        self.root = str(root)
        self.occupancy, self.cameras, self.lidar, self.boxes = occupancy, bool(cameras), bool(lidar), bool(boxes)
        self.camera_maps = tuple(camera_maps)
        self._check_keys()
        self.dense_limit = int(dense_limit)
        self.crop = None if crop is None else (np.asarray(crop[0], float), np.asarray(crop[1], float))
        self.split = split
        store = Store(self.root)
        if store.is_local and not store.fs.exists(store.path("")):
            raise DatasetError(f"{self.root} does not exist: build it with `carlaocc run --root {self.root}`")
        try:
            seqs = {s.sequence_id: s for s in ParquetTable(store, SequenceRecord).load()}
        except StoreError as exc:
            raise DatasetError(f"{self.root}: cannot read the sequences table ({exc})") from None
        if not seqs:
            raise DatasetError(f"{self.root} holds no built dataset (no sequences): run `carlaocc run --root "
                               f"{self.root}`")
        wanted = sorted(seqs) if sequences is None else list(sequences)
        unknown = [s for s in wanted if s not in seqs]
        if unknown:
            raise DatasetError(f"{self.root}: unknown sequence(s) {unknown}")
        if split is not None:
            try:
                assignment = SplitStore(store).load()
            except StoreError as exc:
                raise DatasetError(str(exc)) from None
            wanted = [s for s in wanted if assignment.get(s) == split]
        occ = OccupancyStore(store)
        if voxel_size is None:
            # the finest size every wanted sequence has (a sequence built at none is left out)
            sizes = [set(occ.voxel_sizes(s)) for s in wanted]
            common = set.intersection(*[z for z in sizes if z]) if any(sizes) else set()
            if not common:
                raise DatasetError(f"no voxel size is built for every sequence{f' of the {split} split' if split else ''} "
                                   f"of {self.root}: run `carlaocc run --root {self.root} --voxel-size 0.2`, or pass voxel_size")
            voxel_size = min(common)
        self.voxel_size = float(voxel_size)
        self._grids: dict[str, object] = {}
        for s in wanted:
            grid = occ.stored_grid(s, self.voxel_size)
            if grid is not None:
                self._grids[s] = grid
        if not self._grids:
            where = f"the {split} split of " if split else ""
            raise DatasetError(f"no sequence of {where}{self.root} is voxelized at {self.voxel_size:g} m: run "
                               f"`carlaocc run --root {self.root} --voxel-size {self.voxel_size:g}`")
        frames = ParquetTable(store, FrameRecord).load_arrow(list(self._grids))
        pairs = sorted(zip(frames["sequence_id"].to_pylist(), frames["frame_index"].to_pylist()))
        self._samples: list[tuple[str, int]] = [(s, int(f)) for s, f in pairs]
        self._camera_names = {s: None for s in self._grids}
        if self.occupancy == "dense":
            n = max(int(np.prod(g.shape)) for g in self._grids.values())
            if n > self.dense_limit:
                raise DatasetError(f"a dense frame at {self.voxel_size:g} m has {n:,} voxels (over dense_limit "
                                   f"{self.dense_limit:,}): use occupancy='sparse' or a crop")
        if self.occupancy == "crop":
            n = max(int(np.prod(np.subtract(*reversed(crop_box(g, self.crop))))) for g in self._grids.values())
            if n > self.dense_limit:
                raise DatasetError(f"the crop holds {n:,} voxels at {self.voxel_size:g} m (over dense_limit "
                                   f"{self.dense_limit:,}): crop less, or use occupancy='sparse'")
        self._open: dict | None = None

    # -- the keys a sample carries ------------------------------------------------------------------
    def key_plan(self) -> dict[str, frozenset[str]]:
        """The keys each enabled part of a sample may carry, from the options alone (a part: ``frame``,
        ``occupancy``, ``cameras``, ``lidar``; :class:`carlaocc.data.CarlaOccDataset` adds ``boxes``).
        An occupancy array the root did not store is left out of a sample, never renamed."""
        plan = {"frame": frozenset({"sequence_id", "frame_index", "timestamp", "ego_pose", "lidar_pose", "lidar_to_ego",
                                    "voxel_size", "grid_origin", "grid_shape"})}
        if self.occupancy == "sparse":
            plan["occupancy"] = frozenset({"occ"} | {f"occ_{n}" for n in OCC_ARRAYS if n != "semantic"})
        elif self.occupancy in ("dense", "crop"):
            plan["occupancy"] = frozenset(OCC_ARRAYS) | ({"crop_offset"} if self.occupancy == "crop" else set())
        if self.cameras or self.camera_maps:
            plan["cameras"] = frozenset({"camera_names", "cam_intrinsics", "cam_to_lidar", "cam_to_ego"}
                                        | ({"images"} if self.cameras else set())
                                        | {CAMERA_MAP_PREFIX + m for m in self.camera_maps})
        if self.lidar:
            plan["lidar"] = frozenset({"points", "points_semantic", "points_instance", "points_channel"})
        return plan

    def _check_keys(self) -> None:
        """Refuse options under which two parts of a sample would give one key (one would silently replace the other)."""
        parts = list(self.key_plan().items())
        for a, (name_a, keys_a) in enumerate(parts):
            for name_b, keys_b in parts[a + 1:]:
                clash = keys_a & keys_b
                if clash:
                    raise DatasetError(f"sample keys {sorted(clash)} would be given by both {name_a} and {name_b} "
                                       f"(occupancy={self.occupancy!r}, camera_maps={list(self.camera_maps)}): "
                                       f"one would replace the other")

    # -- pickling: workers get the index, not the open stores or caches ----------------------------
    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_open"] = None
        return state

    def _state(self) -> dict:
        """This process's open stores and per-sequence caches."""
        if self._open is None:

            store = Store(self.root)
            self._open = {"store": store, "occ": OccupancyStore(store), "sensors": SensorStore(store),
                          "lidar": LidarStore(store), "tables": OrderedDict()}
        return self._open

    # -- the sequence API -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._samples)

    def grid(self, seq: str):
        """The :class:`~carlaocc.schemas.grid.GridSpec` sequence ``seq`` was voxelized on."""
        return self._grids[seq]

    @property
    def samples(self) -> list[tuple[str, int]]:
        """``(sequence_id, frame_index)`` of every sample, in order."""
        return list(self._samples)

    def __getitem__(self, index: int) -> dict:
        n = len(self._samples)
        if not isinstance(index, (int, np.integer)) and not (hasattr(index, "ndim") and index.ndim == 0
                                                             and np.issubdtype(getattr(index, "dtype", float), np.integer)):
            raise TypeError(f"sample index {index!r}: an integer")
        if not -n <= int(index) < n:
            raise IndexError(f"sample {index} outside [0, {n})")
        seq, frame = self._samples[int(index)]
        st = self._state()
        grid = self._grids[seq]
        frames, _ = self._tables(seq)
        row = frames[frame]
        lidar_pose = row["lidar_pose"]
        out: dict = {"sequence_id": seq, "frame_index": frame, "timestamp": row["timestamp"],
                     "ego_pose": row["ego_pose"], "lidar_pose": lidar_pose,
                     "lidar_to_ego": np.linalg.inv(row["ego_pose"]) @ lidar_pose,
                     "voxel_size": float(grid.voxel_size), "grid_origin": np.asarray(grid.region_min, np.float64),
                     "grid_shape": np.asarray(grid.shape, np.int64)}
        if self.occupancy != "none":
            out.update(self._occupancy(st["occ"], seq, grid, frame))
        if self.cameras or self.camera_maps:
            out.update(self._cameras(st["sensors"], seq, frame))
        if self.lidar:
            pts = st["lidar"].load(seq, frame)
            out["points"] = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float32)
            out["points_semantic"], out["points_instance"] = pts["semantic"], pts["instance"]
            out["points_channel"] = pts["channel"]
        return out

    def actor_rows(self, index: int) -> list[tuple]:
        """The actors of sample ``index`` as rows of the actors table, world frame: (instance id,
        semantic id, box centre (3,) m, box size (l, w, h) m, yaw, pitch, roll rad, velocity (3,) m/s)."""
        seq, frame = self._samples[int(index)]
        return self._tables(seq)[1].get(frame, [])

    # -- per-sequence tables, cached per process --------------------------------------------------
    def _tables(self, seq: str) -> tuple[dict, dict]:

        cache = self._state()["tables"]
        if seq in cache:
            cache.move_to_end(seq)
            return cache[seq]
        store = self._state()["store"]
        t = ParquetTable(store, FrameRecord).load_arrow([seq]).to_pydict()
        frames = {int(f): {"timestamp": float(ts), "ego_pose": np.asarray(e, np.float64).reshape(4, 4),
                           "lidar_pose": np.asarray(lp, np.float64).reshape(4, 4)}
                  for f, ts, e, lp in zip(t["frame_index"], t["timestamp"], t["ego_pose"], t["lidar_pose"])}
        actors: dict[int, list] = {}
        at = ParquetTable(store, ActorStateRecord)
        if at.exists(seq):
            a = at.load_arrow([seq]).to_pydict()
            for k in range(len(a["frame_index"])):
                actors.setdefault(int(a["frame_index"][k]), []).append(
                    (a["instance_id"][k], a["semantic_id"][k], a["box_center"][k], a["box_size"][k], a["yaw"][k],
                     a["pitch"][k], a["roll"][k], a["velocity"][k]))
        cache[seq] = (frames, actors)
        while len(cache) > _CACHE:
            cache.popitem(last=False)
        return cache[seq]

    # -- occupancy --------------------------------------------------------------------------------
    def _occupancy(self, occ, seq: str, grid, frame: int) -> dict:
        names = [n for n in OCC_ARRAYS if _has(occ, seq, grid, n)]
        shape, chunks, _ = occ.layout(seq, grid, "semantic")
        cx, cy = chunks[1], chunks[2]
        X, Y, Z = shape[1:4]
        if self.occupancy == "sparse":
            return _sparse(occ, seq, grid, frame, names, cx, cy, X, Y)
        if self.occupancy == "dense":
            lo, hi = np.zeros(3, np.int64), np.array([X, Y, Z], np.int64)
        else:
            lo, hi = crop_box(grid, self.crop)
        out = _dense_box(occ, seq, grid, frame, names, cx, cy, lo, hi)
        if self.occupancy == "crop":
            out["crop_offset"] = lo
        return out

    # -- cameras ----------------------------------------------------------------------------------
    def _cameras(self, sensors, seq: str, frame: int) -> dict:
        if self._camera_names.get(seq) is None:
            self._camera_names[seq] = sensors.cameras(seq)
        cams = self._camera_names[seq]
        if not cams:
            raise DatasetError(f"{self.root}: sequence {seq} has no camera maps: run the sensors stage")
        out: dict = {"camera_names": list(cams)}
        K, to_lidar, to_ego, images = [], [], [], []
        maps: dict[str, list] = {m: [] for m in self.camera_maps}
        calib = self._state().setdefault("calib", {})
        for cam in cams:
            if (seq, cam) not in calib:  # once per worker: the calibration, and whether RGB exists
                attrs = sensors.attrs(seq, cam, "depth")
                calib[(seq, cam)] = (np.asarray(attrs["intrinsics"], np.float64),
                                     np.asarray(attrs["camera_to_lidar"], np.float64),
                                     np.asarray(attrs["camera_to_ego"], np.float64), sensors.exists(seq, cam, "rgb"))
            k_, l_, e_, has_rgb = calib[(seq, cam)]
            K.append(k_)
            to_lidar.append(l_)
            to_ego.append(e_)
            if self.cameras:
                if not has_rgb:
                    raise DatasetError(f"{self.root}: {seq}/{cam} has no RGB (built with sensors.rgb off?)")
                images.append(sensors.read_image(seq, cam, frame, "rgb"))
            for m in self.camera_maps:
                maps[m].append(sensors.read_image(seq, cam, frame, m))
        out["cam_intrinsics"], out["cam_to_lidar"], out["cam_to_ego"] = np.stack(K), np.stack(to_lidar), np.stack(to_ego)
        if self.cameras:
            out["images"] = np.stack(images)
        for m, arrays in maps.items():
            out[CAMERA_MAP_PREFIX + m] = np.stack(arrays)
        return out


def crop_box(grid, crop) -> tuple[np.ndarray, np.ndarray]:
    """Voxel index box ``[lo, hi)`` of the voxels whose centres lie in the metre box ``crop``
    (faces included, to a nanometre: a face on a voxel centre takes that voxel on every axis)."""
    voxel_size, o, shape = float(grid.voxel_size), np.asarray(grid.region_min, float), np.asarray(grid.shape)
    eps = 1e-9 / voxel_size
    lo = np.clip(np.ceil((crop[0] - o) / voxel_size - 0.5 - eps), 0, shape).astype(np.int64)
    hi = np.clip(np.floor((crop[1] - o) / voxel_size - 0.5 + eps) + 1, 0, shape).astype(np.int64)
    return lo, np.maximum(hi, lo)


def _has(occ, seq: str, grid, name: str) -> bool:
    try:
        occ.layout(seq, grid, name)
        return True
    except ValueError:
        return False


def _sparse(occ, seq: str, grid, frame: int, names: list[str], cx: int, cy: int, X: int, Y: int) -> dict:
    """The occupied voxels of one frame, gathered chunk by chunk (never the dense frame)."""
    rows, inst, flow, mcam, mlid = [], [], [], [], []
    order_parts, start = [], 0
    for ci in range(-(-X // cx)):
        first = len(rows)
        for cj in range(-(-Y // cy)):
            sem = occ.read_chunk(seq, grid, frame, "semantic", ci, cj)
            if sem is None:
                continue
            # the chunk's occupied voxels in C order within it, found on the flat chunk (a 1-D scan
            # is several times faster than a 3-D nonzero); the other arrays read at the same places
            sem = np.ascontiguousarray(sem)
            bx, by, bz = sem.shape
            flat = np.flatnonzero(sem)
            if not len(flat):
                continue
            ii, rest = np.divmod(flat, by * bz)
            jj, kk = np.divmod(rest, bz)
            row = np.empty((len(flat), 4), np.int32)
            row[:, 0], row[:, 1], row[:, 2], row[:, 3] = ii + ci * cx, jj + cj * cy, kk, sem.reshape(-1)[flat]
            rows.append(row)
            for name, acc, dtype, trailing in (("instance", inst, np.uint32, ()), ("flow", flow, np.float32, (3,)),
                                               ("mask_camera", mcam, bool, ()), ("mask_lidar", mlid, bool, ())):
                if name not in names:
                    continue
                block = occ.read_chunk(seq, grid, frame, name, ci, cj)
                acc.append(np.zeros((len(flat), *trailing), dtype) if block is None else
                           np.ascontiguousarray(block).reshape(len(sem.reshape(-1)), *trailing)[flat].astype(dtype))
        # C order over the grid: within this row of chunks, rows are in (j, k) order per chunk
        # and the chunks in j order, so a stable sort on i alone orders them (i, j, k)
        if len(rows) > first:
            i_col = np.concatenate([r[:, 0] for r in rows[first:]])
            order_parts.append(start + np.argsort(i_col, kind="stable"))
            start += len(i_col)
    occ_rows = np.concatenate(rows) if rows else np.zeros((0, 4), np.int32)
    order = np.concatenate(order_parts) if order_parts else np.zeros(0, np.int64)
    out = {"occ": occ_rows[order]}
    for key, name, acc, dtype, trailing in (("occ_instance", "instance", inst, np.uint32, ()),
                                            ("occ_flow", "flow", flow, np.float32, (3,)),
                                            ("occ_mask_camera", "mask_camera", mcam, bool, ()),
                                            ("occ_mask_lidar", "mask_lidar", mlid, bool, ())):
        if name in names:
            out[key] = (np.concatenate(acc) if acc else np.zeros((0, *trailing), dtype))[order]
    return out


def _dense_box(occ, seq: str, grid, frame: int, names: list[str], cx: int, cy: int, lo: np.ndarray,
               hi: np.ndarray) -> dict:
    """Dense arrays of the voxel box ``[lo, hi)`` of one frame, reading only the chunks it reaches."""
    size = tuple(int(v) for v in hi - lo)
    dtypes = {"semantic": np.uint8, "instance": np.uint32, "flow": np.float32, "mask_camera": bool, "mask_lidar": bool}
    out = {n: np.zeros(size + ((3,) if n == "flow" else ()), dtypes[n]) for n in names}
    if 0 in size:
        return out
    for ci in range(lo[0] // cx, (hi[0] - 1) // cx + 1):
        for cj in range(lo[1] // cy, (hi[1] - 1) // cy + 1):
            # the part of this chunk inside the box, in chunk and in box coordinates
            x0, x1 = max(lo[0], ci * cx), min(hi[0], (ci + 1) * cx)
            y0, y1 = max(lo[1], cj * cy), min(hi[1], (cj + 1) * cy)
            for n in names:
                block = occ.read_chunk(seq, grid, frame, n, ci, cj)
                if block is None:
                    continue
                out[n][x0 - lo[0]:x1 - lo[0], y0 - lo[1]:y1 - lo[1]] = \
                    block[x0 - ci * cx:x1 - ci * cx, y0 - cj * cy:y1 - cj * cy, lo[2]:hi[2]]
    return out
