"""The official CarlaOcc release's layout read as samples: the reading behind
:class:`carlaocc.data.CarlaOccDataset` when its root is a release folder (the authors' download,
or what ``carlaocc export carlaocc-release`` wrote). Same options and the same keys as on a built
root (:class:`carlaocc.catalog.samples.FrameSamples`), where the layout holds them.

What the layout holds (:mod:`carlaocc.catalog.formats.carlaocc_release`) and what a sample gets:

* ``<Town>_Opt_Seq<NN>/poses/lidar.txt`` -> ``lidar_pose``; ``ego_pose`` is the LiDAR pose moved
  down by the authors' LiDAR mount (``lidar_to_ego`` = translation (0, 0, 1.73) m: the release
  holds no ego pose, and ours equals it on the default rig).
* ``occupancy/<grid>/<frame>.npz`` -> ``occ`` / ``occ_instance`` (sparse) or ``semantic`` /
  ``instance`` (dense, crop). ``voxel_size`` picks the grid: 0.1 (``vs_0_1``), 0.2
  (``vs_0_2_forward_view``), 0.4 (``vs_0_4_surround_view``). Instance ids are the release's;
  with our export's ``carlaocc_export.json`` beside them they are mapped back to ours, and the
  sequence ids and frame rate are ours too.
* ``calib/calib.yaml`` -> ``camera_names`` (``cam_XX`` is our ``camera_XX``; the cameras with an
  ``image_XX`` folder in the sequence, or all when none has), ``cam_intrinsics``,
  ``cam_to_lidar`` (the body transform turned to the OpenCV optical frame), ``cam_to_ego``.
* ``rgb/``, ``depth/``, ``semantics/``, ``normal/`` ``image_XX/<frame>.png`` -> ``images``,
  ``cam_depth`` (uint16 to metres; 0, no surface, where it saturates at 80 m: the layout cannot
  tell a farther surface from the sky), ``cam_semantic``
  (CityScapes colours to ids), ``cam_normal`` (each 8-bit step's centre).
* ``lidar/<frame>.ply`` -> ``points``.
* ``splits/<split>.txt`` -> the frames of a split.

Not in the layout, so never in a sample (:meth:`ReleaseSamples.key_plan` leaves them out): the
occupancy ``flow`` and visibility masks, ``points_semantic`` / ``points_instance`` /
``points_channel``, the boxes; ``camera_maps=("instance",)`` is refused. Timestamps are frame
numbers over the rate: the export note's, else the authors' 10 Hz.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from carlaocc.catalog.carla_recording import (DEPTH_RANGE, LIDAR_HEIGHT, OPTICAL_FROM_BODY, RecordingError,
                                              decode_depth, decode_semantics, read_calib, read_ply, read_poses)
from carlaocc.catalog.formats import FormatError
from carlaocc.catalog.formats.carlaocc_npz import load_carlaocc_rows
from carlaocc.catalog.formats.carlaocc_release import RELEASE_GRIDS, release_grid_spec
from carlaocc.catalog.samples import (CAMERA_MAP_PREFIX, DENSE_LIMIT, DatasetError, check_options, crop_box)

__all__ = ["ReleaseSamples", "is_release", "RELEASE_RATE_HZ", "RELEASE_NOTE", "RELEASE_MAP_DIRS"]

RELEASE_RATE_HZ = 10.0  # Hz: the authors' recordings (CARLA's fixed 0.1 s step)
RELEASE_NOTE = "carlaocc_export.json"  # what our export adds beside the layout (ids, rates)
RELEASE_MAP_DIRS = {"rgb": "rgb", "depth": "depth", "semantic": "semantics", "normal": "normal"}
"""Sample camera map -> the release's folder (``<seq>/<folder>/image_XX/<frame:04d>.png``)."""
SEQUENCE_FOLDER = re.compile(r"^Town(\d{2})(?:HD)?_Opt_Seq(\d{2})$")


def is_release(root) -> bool:
    """``root`` is a local folder in the release's layout: ``calib/calib.yaml`` and at least one
    ``Town<NN>_Opt_Seq<NN>/poses/lidar.txt``."""
    try:
        p = Path(str(root))
        return (p / "calib" / "calib.yaml").is_file() and any(
            SEQUENCE_FOLDER.match(d.name) and (d / "poses" / "lidar.txt").is_file() for d in p.iterdir())
    except OSError:
        return False


def _ego_from_lidar() -> np.ndarray:
    """``lidar_to_ego`` of the authors' rig: the LiDAR 1.73 m above the ego origin, no rotation."""
    T = np.eye(4)
    T[2, 3] = LIDAR_HEIGHT
    return T


class ReleaseSamples:
    """Frames of a release folder as samples (see the module doc for what each key comes from).
    Options as :class:`carlaocc.catalog.samples.FrameSamples`; ``sequences`` are the note's ids
    (our sequence ids) or the folder names."""

    def __init__(self, root: str = "data", split: str | None = None, voxel_size: float | None = None,
                 occupancy: str = "sparse", crop: Sequence[Sequence[float]] | None = None, cameras: bool = True,
                 camera_maps: Sequence[str] = (), lidar: bool = True, boxes: bool = True,
                 sequences: Sequence[str] | None = None, dense_limit: int = DENSE_LIMIT) -> None:
        sequences = check_options(occupancy, crop, camera_maps, split, voxel_size, sequences)
        if "instance" in camera_maps:
            raise DatasetError(f"{root}: the release layout holds no camera instance maps: leave 'instance' out of "
                               f"camera_maps")
        self.root = str(root)
        self.occupancy, self.cameras, self.lidar, self.boxes = occupancy, bool(cameras), bool(lidar), bool(boxes)
        self.camera_maps = tuple(camera_maps)
        self.dense_limit = int(dense_limit)
        self.crop = None if crop is None else (np.asarray(crop[0], float), np.asarray(crop[1], float))
        self.split = split
        base = Path(self.root)
        if not is_release(base):
            raise DatasetError(f"{self.root}: not a release folder (calib/calib.yaml and Town<NN>_Opt_Seq<NN>/poses/"
                               f"lidar.txt)")
        # 1. our export's note: folder -> (sequence id, rate) and the exported instance ids back to ours
        note = {}
        if (base / RELEASE_NOTE).is_file():
            try:
                note = json.loads((base / RELEASE_NOTE).read_text())
            except (OSError, ValueError) as exc:
                raise DatasetError(f"{base / RELEASE_NOTE}: unreadable ({exc}); remove it to read the release "
                                   f"without our ids") from None
        by_folder = {v["folder"]: (k, float(v.get("rate_hz", RELEASE_RATE_HZ)))
                     for k, v in note.get("sequences", {}).items()}
        folders = sorted(d.name for d in base.iterdir() if SEQUENCE_FOLDER.match(d.name)
                         and (d / "poses" / "lidar.txt").is_file())
        self._folder = {by_folder.get(f, (f, 0))[0]: f for f in folders}
        self._rate = {by_folder.get(f, (f, 0))[0]: by_folder.get(f, (f, RELEASE_RATE_HZ))[1] for f in folders}
        self._back = {}
        for seq in self._folder:
            table = note.get("instances", {}).get(seq, {})
            # sorted keys ``semantic << 32 | exported id`` and our ids
            pairs = sorted(((int(k.split(":")[0]) << 32) | int(v), int(k.split(":")[1])) for k, v in table.items())
            self._back[seq] = (np.array([p[0] for p in pairs], np.int64), np.array([p[1] for p in pairs], np.uint32))
        wanted = sorted(self._folder) if sequences is None else sequences
        unknown = [s for s in wanted if s not in self._folder]
        if unknown:
            raise DatasetError(f"{self.root}: unknown sequence(s) {unknown} (known: {', '.join(sorted(self._folder))})")
        # 2. the grid of the voxel size
        sizes = {g.voxel_size: g for g in RELEASE_GRIDS}
        if voxel_size is None:  # the finest grid every wanted sequence has
            have = [g.voxel_size for g in RELEASE_GRIDS
                    if all((base / self._folder[s] / "occupancy" / g.name).is_dir() for s in wanted)]
            voxel_size = min(have) if have else RELEASE_GRIDS[0].voxel_size
        match = [g for v, g in sizes.items() if abs(v - float(voxel_size)) < 1e-9]
        if not match:
            raise DatasetError(f"voxel_size={voxel_size!r}: the release's grids are "
                               f"{', '.join(f'{g.voxel_size:g} m ({g.name})' for g in RELEASE_GRIDS)}")
        self._release_grid = match[0]
        self.voxel_size = float(match[0].voxel_size)
        self._spec = release_grid_spec(match[0])
        # 3. the frames: each sequence's poses, in the split when one is asked
        in_split = None
        if split is not None:
            path = base / "splits" / f"{split}.txt"
            if not path.is_file():
                raise DatasetError(f"{path} is missing: pass split=None for every frame")
            in_split = set()
            for line in path.read_text().splitlines():
                parts = line.split()
                if len(parts) == 3:
                    town, sq, fr = parts
                    prefix = "Town10HD_Opt" if town == "10" else f"Town{town}_Opt"
                    in_split.add((f"{prefix}_Seq{sq}", int(fr)))
        self._poses: dict[str, dict[int, np.ndarray]] = {}
        samples = []
        for seq in wanted:
            try:
                poses, _ = read_poses(base / self._folder[seq] / "poses" / "lidar.txt")
            except RecordingError as exc:
                raise DatasetError(str(exc)) from None
            self._poses[seq] = poses
            samples += [(seq, f) for f in sorted(poses) if in_split is None or (self._folder[seq], f) in in_split]
        if not samples:
            raise DatasetError(f"no frame of {'the ' + split + ' split of ' if split else ''}{self.root}")
        self._samples = samples
        self._calib = None
        if occupancy == "dense" and int(np.prod(self._spec.shape)) > self.dense_limit:
            raise DatasetError(f"a dense frame at {self.voxel_size:g} m has {int(np.prod(self._spec.shape)):,} voxels "
                               f"(over dense_limit {self.dense_limit:,}): use occupancy='sparse' or a crop")
        if occupancy == "crop":
            lo, hi = crop_box(self._spec, self.crop)
            if int(np.prod(hi - lo)) > self.dense_limit:
                raise DatasetError(f"the crop holds {int(np.prod(hi - lo)):,} voxels at {self.voxel_size:g} m (over "
                                   f"dense_limit {self.dense_limit:,}): crop less, or use occupancy='sparse'")

    # -- the keys a sample carries ------------------------------------------------------------------
    def key_plan(self) -> dict[str, frozenset[str]]:
        """The keys each part of a sample carries: those of a built root the layout holds."""
        plan = {"frame": frozenset({"sequence_id", "frame_index", "timestamp", "ego_pose", "lidar_pose", "lidar_to_ego",
                                    "voxel_size", "grid_origin", "grid_shape"})}
        if self.occupancy == "sparse":
            plan["occupancy"] = frozenset({"occ", "occ_instance"})
        elif self.occupancy in ("dense", "crop"):
            plan["occupancy"] = frozenset({"semantic", "instance"} | ({"crop_offset"} if self.occupancy == "crop" else set()))
        if self.cameras or self.camera_maps:
            plan["cameras"] = frozenset({"camera_names", "cam_intrinsics", "cam_to_lidar", "cam_to_ego"}
                                        | ({"images"} if self.cameras else set())
                                        | {CAMERA_MAP_PREFIX + m for m in self.camera_maps})
        if self.lidar:
            plan["lidar"] = frozenset({"points"})
        return plan

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def samples(self) -> list[tuple[str, int]]:
        """``(sequence_id, frame_index)`` of every sample, in order."""
        return list(self._samples)

    def grid(self, seq: str):
        """The :class:`~carlaocc.schemas.grid.GridSpec` of the release grid read (every sequence's)."""
        return self._spec

    def actor_rows(self, index: int) -> list[tuple]:
        """No actors: the release layout holds no boxes."""
        return []

    def __getitem__(self, index: int) -> dict:
        n = len(self._samples)
        if not isinstance(index, (int, np.integer)):
            raise TypeError(f"sample index {index!r}: an integer")
        if not -n <= int(index) < n:
            raise IndexError(f"sample {index} outside [0, {n})")
        seq, frame = self._samples[int(index)]
        folder = Path(self.root) / self._folder[seq]
        lidar_pose = self._poses[seq][frame]
        lidar_to_ego = _ego_from_lidar()
        out: dict = {"sequence_id": seq, "frame_index": int(frame), "timestamp": float(frame / self._rate[seq]),
                     "ego_pose": lidar_pose @ np.linalg.inv(lidar_to_ego), "lidar_pose": lidar_pose,
                     "lidar_to_ego": lidar_to_ego, "voxel_size": self.voxel_size,
                     "grid_origin": np.asarray(self._spec.region_min, np.float64),
                     "grid_shape": np.asarray(self._spec.shape, np.int64)}
        if self.occupancy != "none":
            out.update(self._occupancy(seq, folder, frame))
        if self.cameras or self.camera_maps:
            out.update(self._cameras(folder, frame, lidar_to_ego))
        if self.lidar:
            path = folder / "lidar" / f"{frame:04d}.ply"
            try:
                pts = read_ply(path)
            except RecordingError as exc:
                raise DatasetError(f"{exc}: pass lidar=False for a release without LiDAR") from None
            out["points"] = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float32)
        return out

    # -- occupancy ----------------------------------------------------------------------------------
    def _occupancy(self, seq: str, folder: Path, frame: int) -> dict:
        path = folder / "occupancy" / self._release_grid.name / f"{frame:04d}.npz"
        try:
            rows = load_carlaocc_rows(path)
        except FileNotFoundError:
            raise DatasetError(f"{path} is missing: pass occupancy='none', or another voxel_size") from None
        except FormatError as exc:
            raise DatasetError(str(exc)) from None
        if rows.volume_size != self._spec.shape or abs(rows.voxel_size - self.voxel_size) > 1e-9 or \
                not np.allclose(rows.voxel_origin, self._spec.region_min, atol=1e-6):
            raise DatasetError(f"{path}: a {rows.volume_size} grid of {rows.voxel_size:g} m at {rows.voxel_origin}, not "
                               f"the release's {self._release_grid.name}")
        instance = rows.instance
        keys, ours = self._back[seq]
        if len(keys) and len(instance):
            # the exported ids back to ours, per class (a pair the note does not list keeps its id)
            k = (rows.semantic.astype(np.int64) << 32) | instance.astype(np.int64)
            pos = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
            hit = (keys[pos] == k) & (instance != 0)
            instance = np.where(hit, ours[pos], instance).astype(np.uint32)
        if self.occupancy == "sparse":
            occ = np.empty((len(rows.index), 4), np.int32)
            occ[:, :3], occ[:, 3] = rows.index, rows.semantic
            return {"occ": occ, "occ_instance": instance}
        lo, hi = (np.zeros(3, np.int64), np.asarray(self._spec.shape, np.int64)) if self.occupancy == "dense" \
            else crop_box(self._spec, self.crop)
        keep = np.all((rows.index >= lo) & (rows.index < hi), axis=1)
        size = tuple(int(v) for v in hi - lo)
        sem, inst = np.zeros(size, np.uint8), np.zeros(size, np.uint32)
        idx = tuple((rows.index[keep] - lo).T)
        sem[idx], inst[idx] = rows.semantic[keep], instance[keep]
        out = {"semantic": sem, "instance": inst}
        if self.occupancy == "crop":
            out["crop_offset"] = lo
        return out

    # -- cameras ------------------------------------------------------------------------------------
    def _cameras(self, folder: Path, frame: int, lidar_to_ego: np.ndarray) -> dict:
        if self._calib is None:
            try:
                self._calib = read_calib(Path(self.root) / "calib" / "calib.yaml")
            except RecordingError as exc:
                raise DatasetError(str(exc)) from None
        calib = self._calib
        # the calibration's cameras that have images in this sequence (all when none has: then the
        # missing file is named)
        names = sorted(calib.cam_to_lidar)
        shot = [c for c in names if any((folder / d / f"image_{c[4:]}").is_dir() for d in RELEASE_MAP_DIRS.values())]
        names = shot or names
        to_lidar = np.stack([calib.cam_to_lidar[c] @ OPTICAL_FROM_BODY for c in names])
        out: dict = {"camera_names": [c.replace("cam_", "camera_") for c in names],
                     "cam_intrinsics": np.stack([np.asarray(calib.intrinsics, np.float64)] * len(names)),
                     "cam_to_lidar": to_lidar, "cam_to_ego": lidar_to_ego @ to_lidar}
        wanted = (["rgb"] if self.cameras else []) + list(self.camera_maps)
        for m in wanted:
            arrays = [self._image(folder / RELEASE_MAP_DIRS[m] / f"image_{c[4:]}" / f"{frame:04d}.png", m)
                      for c in names]
            out["images" if m == "rgb" else CAMERA_MAP_PREFIX + m] = np.stack(arrays)
        return out

    def _image(self, path: Path, kind: str) -> np.ndarray:
        """One PNG decoded to a sample's camera map (the encodings of the module doc)."""
        try:
            with Image.open(path) as im:
                a = np.asarray(im.convert("RGB") if kind != "depth" else im)
            if kind == "rgb":
                return a
            if kind == "depth":
                d = decode_depth(a.astype(np.uint16) if a.dtype == np.int32 else a)
                return np.where(d >= np.float32(DEPTH_RANGE), np.float32(0.0), d)  # saturated: no surface
            if kind == "semantic":
                return decode_semantics(a)[0]
            # normal: each 8-bit step v holds n in (1 - 2 (v + 1) / 255, 1 - 2 v / 255]; its centre
            return (1.0 - (2.0 * a.astype(np.float32) + 1.0) / 255.0).astype(np.float16)
        except FileNotFoundError:
            what = "cameras=False" if kind == "rgb" else f"camera_maps without {kind!r}"
            raise DatasetError(f"{path} is missing: pass {what}") from None
        except (OSError, RecordingError) as exc:
            raise DatasetError(f"{path}: unreadable ({exc})") from None
