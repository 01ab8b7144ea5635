"""The official CarlaOcc release's folder layout: the one place that writes it.

Facts from the authors' repository (fengyi233/carlaocc: ``docs/source/occ_generation.rst``,
``tutorials/dataset.py``, ``utils/load_utils.py``, ``occupancy_generation/generators/``,
``data_collection/src/data_saver.py``), written anew here::
    <out>/calib/calib.yaml                          cam_settings (width, height, fov, intrinsics) and
                                                    sensors.cam_XX.transform (camera body -> LiDAR, 4x4)
    <out>/splits/{train,val,test}.txt               one line per frame: '<town number> <sequence number> <frame>'
    <out>/Town<NN>_Opt_Seq<NN>/occupancy/<grid>/<frame:04d>.npz
    <out>/Town<NN>_Opt_Seq<NN>/poses/lidar.txt      '%04d' frame + 16 '%.6f' (LiDAR-to-world, row-major)
    <out>/Town<NN>_Opt_Seq<NN>/rgb|depth|semantics|normal/image_XX/<frame:04d>.png
    <out>/Town<NN>_Opt_Seq<NN>/lidar/<frame:04d>.ply   ASCII PLY x y z I, LiDAR frame (y left)

Town 10 is read as ``Town10HD_Opt`` by the release's reader; every other number ``NN`` as
``TownNN_Opt``.

Occupancy ``.npz`` files are :mod:`carlaocc.catalog.formats.carlaocc_npz`'s (keys
``occupancy``, ``voxel_size``, ``voxel_origin``, ``volume_size``; labels ``semantic << 11 |
instance`` as the release's code writes and reads them, or the documentation's
``semantic * 1000 + instance`` by name). The release's three grid configurations are
:data:`RELEASE_GRIDS`; its coarse grids keep, per voxel, the class highest in its
``sem_z_order`` (:data:`RELEASE_PRIORITY`).

Image encodings: depth ``uint16 = round(clip(d, 0, 80) / 80 * 65535)`` (no surface = 80 m);
semantics the class colours (CityScapes palette, RGB); normals ``uint8((1 - n) / 2 * 255)`` of
the OpenCV-frame unit normal (D2NT's ``get_normal_vis``); rgb 8-bit RGB. LiDAR intensity is
CARLA's ray-cast model without noise, ``I = exp(-0.004 * distance)`` (its default atmosphere
attenuation rate).
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import yaml

from carlaocc.catalog.formats.carlaocc_npz import LABEL_LIMITS, check_encoding
from carlaocc.schemas.grid import GridSpec

__all__ = [
    "ATTENUATION", "DEPTH_RANGE", "RELEASE_GRIDS", "RELEASE_PRIORITY", "ReleaseGrid", "release_grid_spec", "encode_depth",
    "instance_lookup", "remap_instances", "encode_normals", "encode_semantics", "release_instance_ids",
    "sequence_folder", "town_numbers", "calib_yaml", "pose_lines", "ply_text", "split_lines",
]  # fmt: skip

DEPTH_RANGE = 80.0  # m: full scale of the uint16 depth PNGs
ATTENUATION = 0.004  # 1/m: CARLA's default LiDAR atmosphere attenuation rate
MOVING_BASE = 1000  # the release's moving-object ids: 1000 + id % 1000 (get_fg_instance_id)

# utils/labels.py ``sem_z_order`` of the release, highest first: the class a coarse voxel of its
# resampled grids keeps (occ_ops.occ_resample_sparse: the highest z-order among the fine voxel
# centres falling in it). Road users (Train, Bus, Truck, Car, Motorcycle, Bicycle, Rider,
# Pedestrian) > Vegetation > Other, Dynamic, Static > TrafficSign, TrafficLight, Pole > Bridge,
# Building, Wall, GuardRail, Fence > Rock, RailTrack, Sidewalk, RoadLine, Road, Ground, Terrain,
# Water. (Sky, top of the release's list, never occupies a voxel.)
RELEASE_PRIORITY: tuple[int, ...] = (11, 17, 16, 15, 14, 18, 19, 13, 12, 9, 22, 21, 20, 8, 7, 6, 26, 3, 4, 28, 5,
                                     29, 27, 2, 24, 1, 25, 10, 23)


@dataclass(frozen=True)
class ReleaseGrid:
    """One of the release's occupancy grids: folder name, voxel size (m), voxel origin (LiDAR
    frame, m) and volume size (voxels)."""

    name: str
    voxel_size: float
    voxel_origin: tuple[float, float, float]
    volume_size: tuple[int, int, int]


RELEASE_GRIDS: tuple[ReleaseGrid, ...] = (
    ReleaseGrid("vs_0_1", 0.1, (-25.6, -25.6, -3.0), (768, 512, 130)),
    ReleaseGrid("vs_0_2_forward_view", 0.2, (0.0, -25.6, -2.4), (256, 256, 32)),
    ReleaseGrid("vs_0_4_surround_view", 0.4, (-25.6, -25.6, -2.4), (128, 128, 16)),
)
"""``docs/source/occ_generation.rst``, "Occupancy grid configurations": the raw 0.1 m grid, the
SSCBench-KITTI-360-like forward view and the Occ3D-nuScenes-like surround view."""


def release_grid_spec(g: ReleaseGrid) -> GridSpec:
    """A release grid as a :class:`GridSpec` (LiDAR frame, metres)."""
    hi = tuple(o + n * g.voxel_size for o, n in zip(g.voxel_origin, g.volume_size))
    spec = GridSpec(region_min=g.voxel_origin, region_max=hi, voxel_size=g.voxel_size)
    if spec.shape != g.volume_size:  # pragma: no cover - the table's numbers are whole voxels
        raise ValueError(f"{g.name}: {spec.shape} voxels, not {g.volume_size}")
    return spec


# ------------------------------------------------------------------ names


def town_numbers(towns: Sequence[str]) -> dict[str, int]:
    """Release town numbers of our towns, in order: a town already named like the release's
    (``Town03_Opt``, ``Town10HD_Opt``) keeps its number; the others take the free numbers of
    1..7, 10, then 11, 12, ... (the release's eight towns first). ``ValueError`` past 99."""

    taken: dict[str, int] = {}
    for t in towns:
        m = re.fullmatch(r"Town(\d{2})(?:HD)?_Opt", t)
        if m and int(m.group(1)) not in taken.values():
            taken[t] = int(m.group(1))
    free = [n for n in [1, 2, 3, 4, 5, 6, 7, 10, *range(11, 100)] if n not in taken.values()]
    out = {}
    for t in towns:
        if t in taken:
            out[t] = taken[t]
        elif free:
            out[t] = free.pop(0)
        else:
            raise ValueError(f"more than 99 towns: the release's two-digit town numbers run out at {t!r}")
    return out


def sequence_folder(town_number: int, sequence_number: int) -> str:
    """``Town<NN>_Opt_Seq<NN>`` as the release's reader builds it (town 10 is ``Town10HD_Opt``)."""
    if not (0 <= sequence_number <= 99 and 1 <= town_number <= 99):
        raise ValueError(f"town {town_number} / sequence {sequence_number}: the release has two-digit numbers")
    prefix = "Town10HD_Opt" if town_number == 10 else f"Town{town_number:02d}_Opt"
    return f"{prefix}_Seq{sequence_number:02d}"


def split_lines(town_number: int, sequence_number: int, frames: Iterable[int]) -> str:
    """Split file lines of one sequence: ``'<town number> <sequence number> <frame>'`` per frame."""
    return "".join(f"{town_number:02d} {sequence_number:02d} {int(f)}\n" for f in frames)


# ------------------------------------------------------------------ instance ids


def release_instance_ids(semantic_ids: np.ndarray, instance_ids: np.ndarray, moving: Iterable[int] = (),
                         encoding: str = "bits", where: str = "") -> dict[tuple[int, int], int]:
    """Exported instance ids of one sequence's (class, instance) pairs (instance 0 = stuff).

    ``moving``: our ids of the simulated actors. Per class, deterministic and stable across the
    sequence's frames; what would collide is renumbered, never merged:
    * ``bits`` (the release's code): placed objects keep their id when every placed id of the
      class is in 1..999, else they are numbered 1, 2, ... in id order; moving ones take
      ``1000 + id % 1000`` when that is unique in the class, else 1000, 1001, ... in id order.
    * ``decimal`` (the release's documentation): ``id % 1000`` when that is unique and non-zero
      in the class, else 1, 2, ... in id order.

    More than a class can hold in a sequence is refused (``ValueError`` naming ``where`` and the
    class)."""
    check_encoding(encoding)
    moving = {int(m) for m in moving}
    pairs = np.unique(np.stack([np.asarray(semantic_ids, np.int64).ravel(), np.asarray(instance_ids, np.int64).ravel()],
                               axis=1), axis=0)  # fmt: skip
    out: dict[tuple[int, int], int] = {}

    def deal(sem: int, ids: list[int], kept: list[int], base: int, room: int) -> None:
        # kept ids when distinct and in range, else base, base + 1, ... in id order
        if len(ids) > room:
            raise ValueError(f"{where}: class {sem} has {len(ids)} instances; the {encoding} encoding holds {room}")
        ok = len(set(kept)) == len(kept) and all(base <= k < base + room for k in kept)
        for n, (i, k) in enumerate(zip(ids, kept)):
            out[(sem, i)] = k if ok else base + n

    for sem in (np.unique(pairs[:, 0]) if len(pairs) else []):
        ids = sorted(int(i) for i in pairs[(pairs[:, 0] == sem) & (pairs[:, 1] != 0), 1])
        if encoding == "decimal":
            deal(int(sem), ids, [i % 1000 for i in ids], 1, 999)
            continue
        placed = [i for i in ids if i not in moving]
        actors = [i for i in ids if i in moving]
        deal(int(sem), placed, placed, 1, 999)
        deal(int(sem), actors, [MOVING_BASE + i % 1000 for i in actors], MOVING_BASE, LABEL_LIMITS["bits"][1] + 1 - MOVING_BASE)
    return out


def instance_lookup(table: Mapping[tuple[int, int], int]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted keys ``semantic << 32 | instance`` of :func:`release_instance_ids`' table and their
    exported ids, for :func:`remap_instances`."""
    if not table:
        return np.zeros(0, np.int64), np.zeros(0, np.uint32)
    keys = np.array([(s << 32) | i for s, i in table], dtype=np.int64)
    vals = np.array(list(table.values()), dtype=np.uint32)
    order = np.argsort(keys)
    return keys[order], vals[order]


def remap_instances(semantic: np.ndarray, instance: np.ndarray, keys: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Exported instance ids (uint32) of one frame: each (class, instance) looked up in
    :func:`instance_lookup`'s table (one object of ours may span two classes, a traffic light's
    head and pole), 0 stays 0. Every non-zero pair must be in the table."""
    out = np.zeros(np.shape(instance), np.uint32)
    nz = np.flatnonzero(np.asarray(instance).reshape(-1))
    if nz.size:
        k = (np.asarray(semantic).reshape(-1)[nz].astype(np.int64) << 32) | np.asarray(instance).reshape(-1)[nz].astype(np.int64)
        pos = np.clip(np.searchsorted(keys, k), 0, max(len(keys) - 1, 0))
        if len(keys) == 0 or not np.array_equal(keys[pos], k):
            raise ValueError("an instance of the frame is missing from the sequence's exported id table")
        out.reshape(-1)[nz] = vals[pos]
    return out


# ------------------------------------------------------------------ calibration, poses, images, points


def calib_yaml(width: int, height: int, fov_deg: float, intrinsics: np.ndarray,
               camera_to_lidar: Mapping[str, np.ndarray]) -> str:
    """``calib/calib.yaml``: ``cam_settings`` and ``sensors.cam_XX.transform`` (camera body frame,
    x forward, y left, z up, to the LiDAR frame; 4x4)."""

    def r6(a):
        return [[round(float(v), 6) for v in row] for row in np.asarray(a)]

    doc = {"cam_settings": {"width": int(width), "height": int(height), "fov": round(float(fov_deg), 6),
                            "intrinsics": r6(intrinsics)},
           "sensors": {name: {"transform": r6(T)} for name, T in sorted(camera_to_lidar.items())}}  # fmt: skip
    return yaml.safe_dump(doc, sort_keys=False)


def pose_lines(poses: Mapping[int, np.ndarray]) -> str:
    """``poses/lidar.txt``: per frame ``'%04d'`` and the 16 values of the 4x4 pose, ``%.6f``."""
    out = []
    for f in sorted(poses):
        M = np.asarray(poses[f], dtype=np.float64).reshape(4, 4)
        if not np.isfinite(M).all():
            raise ValueError(f"frame {f}: non-finite pose")
        out.append(f"{int(f):04d} " + " ".join(f"{v:.6f}" for v in M.ravel()) + "\n")
    return "".join(out)


def encode_depth(depth: np.ndarray) -> np.ndarray:
    """uint16 PNG values of planar depth in metres: ``round(clip(d, 0, 80) / 80 * 65535)``; no
    surface (0 or not finite) is 80 m."""
    d = np.asarray(depth, dtype=np.float64)
    d = np.where(np.isfinite(d) & (d > 0), d, DEPTH_RANGE)
    return np.round(np.clip(d, 0.0, DEPTH_RANGE) / DEPTH_RANGE * 65535.0).astype(np.uint16)


def encode_semantics(semantic: np.ndarray, palette: Sequence[tuple[int, int, int]]) -> np.ndarray:
    """H x W x 3 uint8: each pixel's class colour (ids beyond the palette: black)."""
    lut = np.zeros((256, 3), np.uint8)
    lut[: len(palette)] = np.asarray(palette, dtype=np.uint8)
    return lut[np.asarray(semantic, dtype=np.uint8)]


def encode_normals(normal: np.ndarray) -> np.ndarray:
    """H x W x 3 uint8: ``(1 - n) / 2 * 255`` truncated, ``n`` the OpenCV-frame unit normal."""
    n = np.asarray(normal, dtype=np.float32)
    return (np.clip((1.0 - n) * 0.5, 0.0, 1.0) * 255.0).astype(np.uint8)


def ply_text(points: np.ndarray, intensity: np.ndarray | None = None) -> str:
    """``lidar/<frame>.ply``: ASCII PLY of x y z (LiDAR frame, metres) and the intensity: the
    given one (a recorded scan's), else CARLA's model ``I = exp(-0.004 * distance)``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if intensity is None:
        intensity = np.exp(-ATTENUATION * np.linalg.norm(p, axis=1))
    intensity = np.asarray(intensity, dtype=np.float64).reshape(-1)
    if len(intensity) != len(p):
        raise ValueError(f"lidar PLY: {len(intensity)} intensities for {len(p)} points")
    head = ["ply", "format ascii 1.0", f"element vertex {len(p)}", "property float32 x", "property float32 y",
            "property float32 z", "property float32 I", "end_header"]  # fmt: skip
    buf = io.StringIO()
    buf.write("\n".join(head) + "\n")
    np.savetxt(buf, np.column_stack([p, intensity]), fmt="%.4f %.4f %.4f %.4f")
    return buf.getvalue()


ENCODING_TEXT = {"bits": "semantic << 11 | instance", "decimal": "semantic * 1000 + instance"}

