"""``carlaocc audit FORMAT PATH... [--poses FILE]``: the paper's quality scores (section 4.2,
Table 4) of other occupancy datasets, read through :mod:`catalog.formats`.

Formats, their files, grid and conventions (frame = the frame the grid is expressed in; the
``--poses`` file must hold that frame's poses):

==============  =========================  ======================================  =====================
format          files collected            grid (origin m, voxel m), frame          visibility mask (s_tc)
==============  =========================  ======================================  =====================
occ3d           ``labels.npz``             (-40, -40, -1), 0.4, ego                 ``mask_camera``
semantickitti   ``<stem>.label`` (+ .bin,  (0, -25.6, -2), 0.2, LiDAR (velodyne)    not ``.invalid``
                .invalid, .occluded)
surroundocc     ``*.npy`` (N, 4) rows      (-50, -50, -5), 0.5, LiDAR               none
carlaocc-npz    ``*.npz``                  from each file, LiDAR                    none
==============  =========================  ======================================  =====================

Labels are mapped to an internal uint8 grid where 0 is free (the metrics' convention) and every
dataset class keeps its own id (Occ3D: ids 0-16 -> 1-17, free 17 -> 0; SemanticKITTI: the 20
learning ids, 0 = empty; SurroundOcc: label + 1, a missing row = free, label 0 "noise" counted as a
class; CarlaOcc: its ids). Results are reported with the dataset's own ids and names. ``s_sc`` is
computed on the labels as published (SemanticKITTI's invalid voxels included: the score is about
the ground truth grid, not its evaluation mask). Dynamic classes excluded from ``s_tc``: the road
users (Occ3D/SurroundOcc bicycle, bus, car, construction_vehicle, motorcycle, pedestrian, trailer,
truck; SemanticKITTI car ... motorcyclist; CarlaOcc the taxonomy's dynamic classes).

Paths: each PATH is a file of the format or a directory searched recursively; a directory's files
are sorted by path, PATH arguments keep their order, and the resulting order is taken as the
temporal order (``s_tc`` compares consecutive frames).

``--poses``: one 4x4 grid-frame-to-world pose per frame, in the same order: ``.npy`` of shape
(N, 4, 4), (N, 3, 4), (N, 16) or (N, 12); ``.json`` a list of such matrices (nested or flat
row-major), or ``{"poses": [...]}``; any other file is text with one pose per line, 12 (3x4, KITTI
``poses.txt``) or 16 (4x4) numbers row-major (blank and ``#`` lines skipped). KITTI's
``poses.txt`` holds camera-0 poses: give ``--calib calib.txt`` (its ``Tr`` line, velodyne to
camera 0) and they are turned into LiDAR poses ``inv(Tr) @ P @ Tr``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import numpy as np
import typer

from catalog.formats import (FormatError, load_carlaocc_npz, load_occ3d, load_semantickitti, load_surroundocc,
                             surroundocc_to_dense, to_learning)
from catalog.formats.occ3d import OCC3D_FREE, OCC3D_RANGE, OCC3D_VOXEL_SIZE
from catalog.formats.semantickitti import SEMANTICKITTI_RANGE, SEMANTICKITTI_VOXEL_SIZE
from catalog.formats.surroundocc import SURROUNDOCC_RANGE, SURROUNDOCC_SHAPE, SURROUNDOCC_VOXEL_SIZE
from schemas import taxonomy

if TYPE_CHECKING:
    from stages.metrics import ContinuityCounts, TemporalCounts


class AuditError(ValueError):
    """Bad audit input (unknown format, no files, unreadable file, pose count mismatch)."""


@dataclass(frozen=True)
class AuditFrame:
    """One frame, ready for the metrics: internal uint8 labels (0 = free), an optional visibility
    mask (True = observed) and the grid geometry (metres, in the dataset's grid frame)."""

    path: str
    semantic: np.ndarray
    mask: np.ndarray | None
    voxel_size: float
    origin: tuple[float, float, float]


@dataclass(frozen=True)
class DatasetFormat:
    """How to find, read and name one dataset layout."""

    name: str
    dataset: str  # the name printed in the table
    suffix: str  # file name ending collected from directories
    read: Callable[[Path], AuditFrame]
    class_names: tuple[str, ...]  # dataset id -> name
    to_dataset_id: Callable[[int], int]  # internal id -> dataset id
    dynamic: tuple[int, ...]  # internal ids of the moving classes
    mask: str  # what the visibility mask is, for the report
    accept: Callable[[Path], bool] = lambda p: True  # filter of the files found in directories


_NUSC_DYNAMIC = ("bicycle", "bus", "car", "construction_vehicle", "motorcycle", "pedestrian", "trailer", "truck")


def _origin(rng: Sequence[float]) -> tuple[float, float, float]:
    return (float(rng[0]), float(rng[1]), float(rng[2]))


def _read_occ3d(path: Path) -> AuditFrame:
    f = load_occ3d(path)
    sem = f.semantics
    if sem.size and int(sem.max()) >= 255:
        raise FormatError(f"{path}: Occ3D id {int(sem.max())} does not fit the audit's uint8 ids (0..254)")
    # free (17) -> 0, class k -> k + 1
    lut = (np.arange(256) + 1).astype(np.uint8)
    lut[OCC3D_FREE] = 0
    return AuditFrame(str(path), lut[sem], f.mask_camera.astype(bool), OCC3D_VOXEL_SIZE, _origin(OCC3D_RANGE))


def _read_semantickitti(path: Path) -> AuditFrame:
    v = load_semantickitti(path.parent, path.name[: -len(".label")])
    try:
        sem = to_learning(v.labels)
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return AuditFrame(str(path), sem, ~v.invalid, SEMANTICKITTI_VOXEL_SIZE, _origin(SEMANTICKITTI_RANGE))


def _read_surroundocc(path: Path) -> AuditFrame:
    rows = load_surroundocc(path)
    if len(rows) and int(rows[:, 3].max()) >= 255:
        raise FormatError(f"{path}: label {int(rows[:, 3].max())} does not fit the audit's uint8 ids (0..254)")
    shifted = rows.copy()
    shifted[:, 3] += 1  # label k -> k + 1 so that 0 can be free (SurroundOcc's label 0 is "noise")
    try:
        sem = surroundocc_to_dense(shifted, SURROUNDOCC_SHAPE, free=0)
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return AuditFrame(str(path), sem, None, SURROUNDOCC_VOXEL_SIZE, _origin(SURROUNDOCC_RANGE))


def _read_carlaocc(path: Path) -> AuditFrame:
    f = load_carlaocc_npz(path)
    return AuditFrame(str(path), f.semantic, None, f.voxel_size, f.voxel_origin)


_OCC3D_NAMES = taxonomy.OCC3D_NUSCENES_NAMES
_SURROUNDOCC_NAMES = ("noise",) + _OCC3D_NAMES[1:17]  # nuScenes-lidarseg learning ids 0-16

FORMATS: dict[str, DatasetFormat] = {
    "occ3d": DatasetFormat(
        "occ3d", "Occ3D-nuScenes", "labels.npz", _read_occ3d, _OCC3D_NAMES, lambda i: i - 1,
        tuple(_OCC3D_NAMES.index(n) + 1 for n in _NUSC_DYNAMIC), "mask_camera"),
    "semantickitti": DatasetFormat(
        "semantickitti", "SemanticKITTI", ".label", _read_semantickitti, taxonomy.SEMANTICKITTI_NAMES,
        lambda i: i, tuple(range(1, 9)), "not .invalid",
        # voxel scans only: the point-cloud labels/*.label of a sequence have no .invalid beside them
        accept=lambda p: p.with_suffix(".invalid").is_file()),
    "surroundocc": DatasetFormat(
        "surroundocc", "SurroundOcc", ".npy", _read_surroundocc, _SURROUNDOCC_NAMES, lambda i: i - 1,
        tuple(_SURROUNDOCC_NAMES.index(n) + 1 for n in _NUSC_DYNAMIC), "none"),
    "carlaocc-npz": DatasetFormat(
        "carlaocc-npz", "CarlaOcc", ".npz", _read_carlaocc, tuple(c.name for c in taxonomy.CLASSES),
        lambda i: i, taxonomy.dynamic_ids(), "none"),
}


def dataset_format(name: str) -> DatasetFormat:
    try:
        return FORMATS[name]
    except KeyError:
        raise AuditError(f"unknown format {name!r}; choose one of {', '.join(FORMATS)}") from None


def collect_files(fmt: DatasetFormat, paths: Iterable[str | os.PathLike]) -> list[Path]:
    """The format's files under ``paths`` (files as given, directories searched recursively and
    sorted), in order; an error names a missing path or a directory without any file."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_file():
            out.append(p)
        elif p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.is_file() and q.name.endswith(fmt.suffix) and fmt.accept(q))
            if not found:
                raise AuditError(f"no {fmt.name} files (*{fmt.suffix}) under {p}")
            out.extend(found)
        else:
            raise AuditError(f"{p}: no such file or directory")
    if not out:
        raise AuditError("no input paths given")
    return out


def read_frames(fmt: DatasetFormat, files: Sequence[Path]) -> Iterator[AuditFrame]:
    """Read the files one at a time; an unreadable one raises :class:`AuditError` naming it."""
    for path in files:
        try:
            yield fmt.read(path)
        except (FormatError, OSError, ValueError) as exc:
            msg = str(exc)
            raise AuditError(msg if str(path) in msg else f"{path}: {msg}") from None


# -- poses -----------------------------------------------------------------------------------------
def _as_poses(values, where: str) -> np.ndarray:
    """(N, 4, 4) float64 from (N, 4, 4), (N, 3, 4), (N, 16) or (N, 12) values."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise AuditError(f"{where}: poses are not numbers ({exc})") from None
    if a.ndim == 2 and a.shape[1] in (12, 16):
        a = a.reshape(len(a), a.shape[1] // 4, 4)
    if a.ndim != 3 or a.shape[1:] not in ((3, 4), (4, 4)):
        raise AuditError(f"{where}: expected N poses of 3x4 or 4x4 (12 or 16 numbers), got shape {a.shape}")
    if a.shape[1] == 3:
        a = np.concatenate([a, np.broadcast_to([[[0.0, 0.0, 0.0, 1.0]]], (len(a), 1, 4))], axis=1)
    if not np.isfinite(a).all():
        raise AuditError(f"{where}: poses must be finite")
    bad = np.flatnonzero(~np.isclose(np.linalg.det(a[:, :3, :3]), 1.0, atol=1e-3))
    if bad.size:
        raise AuditError(f"{where}: pose {int(bad[0])} has no rotation part (det {np.linalg.det(a[bad[0], :3, :3]):.4g})")
    return a


def load_poses(path: str | os.PathLike) -> np.ndarray:
    """(N, 4, 4) poses from a ``.npy``, ``.json`` or text file (module docstring)."""
    p = Path(path)
    try:
        if p.suffix == ".npy":
            return _as_poses(np.load(p, allow_pickle=False), str(p))
        text = p.read_text()
    except (OSError, ValueError) as exc:
        raise AuditError(f"{p}: cannot read poses ({exc})") from None
    if p.suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise AuditError(f"{p}: not JSON ({exc})") from None
        if isinstance(data, dict):
            if "poses" not in data:
                raise AuditError(f"{p}: a JSON object must hold the poses under \"poses\"")
            data = data["poses"]
        return _as_poses(data, str(p))
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            values = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise AuditError(f"{p}:{n}: not numbers: {line[:60]!r}") from None
        if len(values) not in (12, 16):
            raise AuditError(f"{p}:{n}: a pose is 12 (3x4) or 16 (4x4) numbers, got {len(values)}")
        rows.append(values if len(values) == 16 else values + [0.0, 0.0, 0.0, 1.0])
    if not rows:
        raise AuditError(f"{p}: no poses")
    return _as_poses(rows, str(p))


def load_kitti_calib(path: str | os.PathLike) -> np.ndarray:
    """The 4x4 velodyne-to-camera-0 transform from a KITTI ``calib.txt`` (its ``Tr:`` line)."""
    p = Path(path)
    try:
        lines = p.read_text().splitlines()
    except OSError as exc:
        raise AuditError(f"{p}: cannot read calibration ({exc})") from None
    for line in lines:
        key, _, rest = line.partition(":")
        if key.strip() == "Tr":
            return _as_poses([rest.split()], f"{p} (Tr)")[0]
    raise AuditError(f"{p}: no 'Tr:' line (velodyne to camera 0)")


# -- the audit ---------------------------------------------------------------------------------------
@dataclass
class AuditResult:
    """Scores of one audited set of frames; counts indexed by internal id."""

    fmt: DatasetFormat
    frames: list[dict] = field(default_factory=list)  # path, s_sc, occupied, isolated
    pairs: list[dict] = field(default_factory=list)  # t, s_tc, intersection, union
    continuity: ContinuityCounts | None = None
    temporal: TemporalCounts | None = None  # None without poses

    @property
    def s_sc(self) -> float:
        return self.continuity.score

    @property
    def s_tc(self) -> float | None:
        return None if self.temporal is None else self.temporal.score

    def per_class(self) -> list[dict]:
        """One row per class present: dataset id, name and its counts."""
        rows = []
        for i in range(1, 256):
            occ, iso = int(self.continuity.occupied[i]), int(self.continuity.isolated[i])
            inter = int(self.temporal.intersection[i]) if self.temporal is not None else 0
            union = int(self.temporal.union[i]) if self.temporal is not None else 0
            if occ or union:
                did = self.fmt.to_dataset_id(i)
                name = self.fmt.class_names[did] if 0 <= did < len(self.fmt.class_names) else f"id {did}"
                row = {"id": did, "name": name, "occupied": occ, "isolated": iso,
                       "s_sc": _nan_to_none(1 - iso / occ if occ else float("nan"))}
                if self.temporal is not None:
                    row |= {"intersection": inter, "union": union,
                            "iou": _nan_to_none(inter / union if union else float("nan"))}
                rows.append(row)
        return rows

    def to_json(self) -> dict:
        c, t = self.continuity, self.temporal
        return {
            "format": self.fmt.name,
            "dataset": self.fmt.dataset,
            "frames": len(self.frames),
            "s_sc": _nan_to_none(self.s_sc),
            "occupied": int(c.occupied[1:].sum()),
            "isolated": int(c.isolated[1:].sum()),
            "s_tc": None if t is None else _nan_to_none(t.score),
            "s_tc_class_mean": None if t is None else _nan_to_none(t.mean_class_iou()),
            "intersection": None if t is None else t.total_intersection,
            "union": None if t is None else t.total_union,
            "visibility_mask": self.fmt.mask,
            "per_frame": self.frames,
            "per_pair": self.pairs,
            "per_class": self.per_class(),
        }


def _nan_to_none(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def audit(fmt: DatasetFormat, files: Sequence[Path], poses: np.ndarray | None = None) -> AuditResult:
    """s_sc per frame and over the set; with ``poses`` (one per file), s_tc per consecutive pair
    and over the set. Frames are read and scored one at a time (two in memory)."""
    from stages.metrics import (empty_temporal_counts, sequence_continuity, spatial_continuity_counts,
                                static_table, temporal_consistency_counts)

    if poses is not None and len(poses) != len(files):
        raise AuditError(f"{len(poses)} poses for {len(files)} frames: give one pose per frame, in order")
    static = static_table(fmt.dynamic)
    result = AuditResult(fmt)
    counts, pair_counts = [], []
    prev: AuditFrame | None = None
    for t, frame in enumerate(read_frames(fmt, files)):
        c = spatial_continuity_counts(frame.semantic)
        counts.append(c)
        result.frames.append({"path": frame.path, "s_sc": _nan_to_none(c.score),
                              "occupied": int(c.occupied[1:].sum()), "isolated": int(c.isolated[1:].sum())})
        if poses is not None and prev is not None:
            use_mask = prev.mask is not None and frame.mask is not None
            tc = temporal_consistency_counts(
                prev.semantic, frame.semantic, poses[t - 1], poses[t], prev.voxel_size, prev.origin,
                mask_t=prev.mask if use_mask else None, mask_t1=frame.mask if use_mask else None,
                static=static, voxel_size_t1=frame.voxel_size, origin_t1=frame.origin)
            pair_counts.append(tc)
            result.pairs.append({"t": t - 1, "s_tc": _nan_to_none(tc.score),
                                 "intersection": tc.total_intersection, "union": tc.total_union})
        prev = frame
    result.continuity = sequence_continuity(counts)
    if poses is not None:
        result.temporal = sum(pair_counts, empty_temporal_counts())
    return result


def _fmt(v: float | None, digits: int = 4) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def format_table(result: AuditResult, per_frame: bool = False) -> str:
    """The paper's Table 4 columns (dataset, frames, s_sc, s_tc) plus the voxel counts."""
    c = result.continuity
    lines = []
    if per_frame:
        lines.append(f"{'frame':>6}  {'s_sc':>7}  {'occupied':>12}  {'isolated':>10}  {'s_tc (t, t+1)':>13}  path")
        tc = {p["t"]: p["s_tc"] for p in result.pairs}
        for t, f in enumerate(result.frames):
            lines.append(f"{t:>6}  {_fmt(f['s_sc']):>7}  {f['occupied']:>12,}  {f['isolated']:>10,}  "
                         f"{_fmt(tc.get(t)):>13}  {f['path']}")
        lines.append("")
    lines.append(f"{'dataset':<16} {'frames':>7} {'s_sc':>7} {'s_tc':>7} {'occupied':>14} {'isolated':>12}")
    lines.append(f"{result.fmt.dataset:<16} {len(result.frames):>7} {_fmt(result.s_sc):>7} {_fmt(result.s_tc):>7} "
                 f"{int(c.occupied[1:].sum()):>14,} {int(c.isolated[1:].sum()):>12,}")
    return "\n".join(lines)


def audit_command(
    fmt: str,
    paths: list[str],
    poses: str | None = None,
    calib: str | None = None,
    json_out: str | None = None,
    per_frame: bool = False,
) -> tuple[AuditResult, str]:
    """The CLI's work: (result, printed table). Raises :class:`AuditError` on bad input."""
    spec = dataset_format(fmt)
    files = collect_files(spec, paths)
    pose_array = load_poses(poses) if poses is not None else None
    if calib is not None:
        if pose_array is None:
            raise AuditError("--calib converts --poses from camera 0 to the LiDAR: give --poses too")
        tr = load_kitti_calib(calib)
        pose_array = np.linalg.inv(tr) @ pose_array @ tr
    if pose_array is not None and len(pose_array) != len(files):
        raise AuditError(f"{poses}: {len(pose_array)} poses for {len(files)} {spec.name} frames "
                         f"(one pose per frame, in order)")
    result = audit(spec, files, pose_array)
    if json_out is not None:
        out = Path(json_out)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            tmp = out.with_name(out.name + ".tmp")
            tmp.write_text(json.dumps(result.to_json(), indent=1))
            tmp.replace(out)
        except OSError as exc:
            raise AuditError(f"cannot write {out}: {exc.strerror or exc}") from None
    return result, format_table(result, per_frame)


def audit_cli(
    fmt: Annotated[str, typer.Argument(metavar="FORMAT", help=f"one of: {', '.join(FORMATS)}")],
    paths: Annotated[list[str], typer.Argument(metavar="PATH...", help="files of the format or directories "
                                               "(searched recursively, sorted); their order is the frame order")],
    poses: Annotated[Optional[str], typer.Option("--poses", help="one 4x4 grid-frame-to-world pose per frame: "
                                                 ".npy (N,4,4)/(N,3,4), .json, or text with 12/16 numbers a line "
                                                 "(KITTI poses.txt); enables s_tc")] = None,
    calib: Annotated[Optional[str], typer.Option("--calib", help="KITTI calib.txt: turn camera-0 --poses into "
                                                 "LiDAR poses with its Tr")] = None,
    json_out: Annotated[Optional[str], typer.Option("--json", help="write the scores (per frame, pair, class) "
                                                    "as JSON here")] = None,
    per_frame: Annotated[bool, typer.Option("--per-frame", help="print a row per frame too")] = False,
) -> None:
    """Quality scores of another dataset: spatial continuity s_sc, and temporal consistency s_tc
    with --poses (paper section 4.2, Table 4). Formats: occ3d, semantickitti, surroundocc,
    carlaocc-npz."""
    try:
        _, table = audit_command(fmt, paths, poses, calib, json_out, per_frame)
    except AuditError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(table)
