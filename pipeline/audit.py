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
truck; SemanticKITTI car ... motorcyclist; CarlaOcc the taxonomy's dynamic classes). An occ3d
file must be Occ3D-nuScenes' (200, 200, 16) grid with ids 0..17 (the geometry above is assumed):
another shape or a larger id is refused, naming the file.

Paths and sequences: each PATH is a file of the format or a directory searched recursively (a
file found twice is audited once). The files are split into **sequences** and ``s_tc`` only pairs
consecutive frames of one sequence (its counts are summed over the sequences):

* occ3d: the scene directory, ``gts/<scene>/<sample_token>/labels.npz`` (the grandparent of the
  file). Sample tokens are random hex: a path carries **no time order**, so ``s_tc`` takes the
  order from the keyed ``--poses`` form below;
* semantickitti: the ``voxels`` directory of one sequence (the file's parent);
* surroundocc, carlaocc-npz: the file's parent directory.

Sequences are listed in the order of their first file (directories sorted by path, PATH
arguments in their order). Within a sequence the files of semantickitti, surroundocc and
carlaocc-npz are sorted numerically by their frame number (the file name without its ending,
``000005.label`` -> 5) when every name is a number, else kept in path order; occ3d files are
listed in path order. That listing is the per-frame table's order and the order of the first
``--poses`` form.

``--poses`` (grid-frame-to-world 4x4 poses; a pose is a 4x4 or 3x4 matrix, or 16 or 12 numbers
row-major) in one of two forms:

* **Keyed** (required for occ3d sequences of more than one frame): a ``.json`` list of
  ``{"frame": F, "pose": [...]}`` in **time order** (or ``{"poses": [that list]}``). ``F`` is the
  sample token (occ3d: the name of the directory holding ``labels.npz``; other formats: the file
  name without its ending, e.g. ``000005``), or the file's path relative to the PATH argument it
  was found under (``scene-0001/0b22/labels.npz``), or the path as listed. The frames of each
  sequence are ordered as the list orders them; frames without an entry are left out of ``s_tc``
  (counted as ``frames_without_pose``; they still count for ``s_sc``); entries naming no audited
  file are ignored (``poses_unmatched``), but at least one must match.
* **One pose per frame in the order the files are listed** (above): ``.npy`` of shape (N, 4, 4),
  (N, 3, 4), (N, 16) or (N, 12); ``.json`` a list of such matrices or ``{"poses": [...]}``; any
  other file is text with one pose per line, 12 (3x4, KITTI ``poses.txt``) or 16 (4x4) numbers
  row-major (blank and ``#`` lines skipped). Refused for occ3d when a scene has more than one
  frame (no time order: use the keyed form). For formats whose file names are frame numbers
  (semantickitti, surroundocc, carlaocc-npz) a list **longer** than the frames of a single
  sequence is indexed by the frame number: frame ``000005`` takes pose 5. That is KITTI's
  ``poses.txt``, one pose per LiDAR scan, while SemanticKITTI's voxel labels exist only for every
  5th scan (000000, 000005, ...).

KITTI's ``poses.txt`` holds camera-0 poses: give ``--calib calib.txt`` (its ``Tr`` line, velodyne
to camera 0) and they are turned into LiDAR poses ``inv(Tr) @ P @ Tr`` (either form).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import numpy as np
import typer

from carlaocc.catalog.formats import (FormatError, atomic_write, load_carlaocc_npz, load_occ3d, load_semantickitti,
                             load_surroundocc, surroundocc_to_dense, to_learning)
from carlaocc.catalog.formats.occ3d import OCC3D_FREE, OCC3D_RANGE, OCC3D_SHAPE, OCC3D_VOXEL_SIZE
from carlaocc.catalog.formats.semantickitti import SEMANTICKITTI_RANGE, SEMANTICKITTI_VOXEL_SIZE
from carlaocc.catalog.formats.surroundocc import SURROUNDOCC_RANGE, SURROUNDOCC_SHAPE, SURROUNDOCC_VOXEL_SIZE
from carlaocc.schemas import taxonomy

if TYPE_CHECKING:
    from carlaocc.stages.metrics import ContinuityCounts, TemporalCounts


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
    sequence: Callable[[Path], Path] = lambda p: p.parent  # the directory of the file's sequence
    numbered: bool = True  # file names are frame numbers (their time order)
    token: Callable[[Path], str] | None = None  # a frame's short name for keyed poses (default: its stem)

    def stem(self, path: Path) -> str:
        """The file name without the format's ending (``000005.label`` -> ``000005``)."""
        name = path.name
        return name[: -len(self.suffix)] if name.endswith(self.suffix) and name != self.suffix else path.stem

    def frame_number(self, path: Path) -> int | None:
        """The frame number in the file name, or None when the name is not a number."""
        s = self.stem(path)
        return int(s) if re.fullmatch(r"[0-9]+", s) else None

    def frame_token(self, path: Path) -> str:
        return self.token(path) if self.token is not None else self.stem(path)


_NUSC_DYNAMIC = ("bicycle", "bus", "car", "construction_vehicle", "motorcycle", "pedestrian", "trailer", "truck")


def _origin(rng: Sequence[float]) -> tuple[float, float, float]:
    return (float(rng[0]), float(rng[1]), float(rng[2]))


def _read_occ3d(path: Path) -> AuditFrame:
    f = load_occ3d(path)
    sem = f.semantics
    # the reader takes any Occ3D variant; the audit's geometry and names are Occ3D-nuScenes'
    if sem.shape != OCC3D_SHAPE:
        raise FormatError(f"{path}: Occ3D-nuScenes grids are {OCC3D_SHAPE} (0.4 m from {OCC3D_RANGE[:3]}), "
                          f"got {sem.shape}")
    if sem.size and int(sem.max()) > OCC3D_FREE:
        raise FormatError(f"{path}: Occ3D-nuScenes ids are 0..{OCC3D_FREE} ({OCC3D_FREE} = free), "
                          f"found {int(sem.max())}")
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
        tuple(_OCC3D_NAMES.index(n) + 1 for n in _NUSC_DYNAMIC), "mask_camera",
        # gts/<scene>/<sample_token>/labels.npz: the scene is the sequence, the token names the frame
        sequence=lambda p: p.parent.parent, numbered=False, token=lambda p: p.parent.name),
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


@dataclass(frozen=True)
class InputFile:
    """One collected file and the PATH argument it was found under (for keyed poses)."""

    path: Path
    root: Path


def collect_inputs(fmt: DatasetFormat, paths: Iterable[str | os.PathLike]) -> list[InputFile]:
    """The format's files under ``paths`` (files as given, directories searched recursively and
    sorted by path), each once, in that order; an error names a missing path or a directory
    without any file."""
    out: list[InputFile] = []
    seen: set[str] = set()
    for raw in paths:
        p = Path(raw)
        if p.is_file():
            found = [p]
        elif p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.is_file() and q.name.endswith(fmt.suffix) and fmt.accept(q))
            if not found:
                raise AuditError(f"no {fmt.name} files (*{fmt.suffix}) under {p}")
        else:
            raise AuditError(f"{p}: no such file or directory")
        for q in found:
            key = os.path.normcase(os.path.abspath(q))
            if key not in seen:  # a file under two PATH arguments is one frame
                seen.add(key)
                out.append(InputFile(q, p))
    if not out:
        raise AuditError("no input paths given")
    return out


def group_sequences(fmt: DatasetFormat, files: Sequence[Path]) -> list[tuple[str, list[Path]]]:
    """``(sequence directory, files)`` per sequence (module docstring), in the order of each
    sequence's first file; numbered files sorted by frame number, others kept in the given order."""
    groups: dict[str, tuple[str, list[Path]]] = {}
    for f in files:
        seq = fmt.sequence(f)
        key = os.path.normcase(os.path.abspath(seq))
        groups.setdefault(key, (str(seq), []))[1].append(f)
    out = []
    for name, fs in groups.values():
        numbers = [fmt.frame_number(f) for f in fs]
        if fmt.numbered and None not in numbers:
            fs = [f for _, f in sorted(zip(numbers, fs), key=lambda nf: nf[0])]  # stable: ties keep path order
        out.append((name, fs))
    return out


def read_frame(fmt: DatasetFormat, path: Path) -> AuditFrame:
    """Read one file; an unreadable one raises :class:`AuditError` naming it once (a reader's
    message that names it, or another file of its scan, is not prefixed)."""
    try:
        return fmt.read(path)
    except (FormatError, OSError, ValueError) as exc:
        msg = str(exc)
        named = str(path) in msg or str(path.with_name(fmt.stem(path))) in msg
        raise AuditError(msg if named else f"{path}: {msg}") from None


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


@dataclass(frozen=True)
class KeyedPoses:
    """The keyed ``--poses`` form: ``frames[i]`` (a sample token or a path) has ``poses[i]``
    (4x4, grid frame to world), listed in time order."""

    frames: tuple[str, ...]
    poses: np.ndarray  # (N, 4, 4) float64


def _keyed_poses(entries: list, where: str) -> KeyedPoses:
    """:class:`KeyedPoses` from a JSON list of ``{"frame": str, "pose": 4x4 | 3x4 | 16 | 12 numbers}``."""
    frames, flat, seen = [], [], set()
    for n, e in enumerate(entries):
        if not isinstance(e, dict) or not {"frame", "pose"} <= e.keys():
            raise AuditError(f"{where}: entry {n} must be {{\"frame\": ..., \"pose\": ...}}, got {str(e)[:60]}")
        if not isinstance(e["frame"], str) or not e["frame"]:
            raise AuditError(f"{where}: entry {n}: \"frame\" must be a sample token or a path (a string), "
                             f"got {e['frame']!r}")
        try:
            values = np.asarray(e["pose"], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            values = np.zeros(0)
        if values.size not in (12, 16):
            raise AuditError(f"{where}: entry {n} ({e['frame']}): a pose is a 4x4 or 3x4 matrix or 16 or 12 numbers")
        if e["frame"] in seen:
            raise AuditError(f"{where}: frame {e['frame']!r} is listed more than once")
        seen.add(e["frame"])
        frames.append(e["frame"])
        flat.append(values if values.size == 16 else np.concatenate([values, [0.0, 0.0, 0.0, 1.0]]))
    return KeyedPoses(tuple(frames), _as_poses(flat, where))


def load_poses(path: str | os.PathLike) -> np.ndarray | KeyedPoses:
    """(N, 4, 4) poses, one per listed frame, from a ``.npy``, ``.json`` or text file, or
    :class:`KeyedPoses` from a JSON list of ``{"frame", "pose"}`` objects (module docstring)."""
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
        if isinstance(data, list) and data and isinstance(data[0], dict):
            return _keyed_poses(data, str(p))
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


# -- sequences and their poses --------------------------------------------------------------------
@dataclass(frozen=True)
class AuditSequence:
    """The frames of one sequence: those with a pose first, in time order, then those without
    (left out of s_tc). ``poses`` is None when the audit has no poses at all."""

    name: str
    files: tuple[Path, ...]
    poses: tuple[np.ndarray | None, ...] | None = None


_FIVE = "SemanticKITTI voxel files are every 5th scan (000000, 000005, ...), KITTI poses.txt has one pose per scan"


def _by_frame_number(fmt: DatasetFormat, files: list[Path], poses: np.ndarray, where: str) -> list[np.ndarray]:
    """Pose ``int(stem)`` of a per-scan pose list for each numbered file."""
    out = []
    for f in files:
        k = fmt.frame_number(f)
        if k is None:
            raise AuditError(f"{where}: {len(poses)} poses for fewer {fmt.name} frames, and {f.name} has no frame "
                             f"number to pick its pose by")
        if k >= len(poses):
            raise AuditError(f"{where}: {len(poses)} poses, none for frame {k} ({f}); {_FIVE}: give that "
                             f"sequence's full poses.txt")
        out.append(poses[k])
    return out


def _ordered(fmt: DatasetFormat, groups: list[tuple[str, list[Path]]], poses: np.ndarray,
             where: str) -> list[AuditSequence]:
    """Poses given one per listed frame (or, for numbered files of one sequence, one per scan)."""
    n = sum(len(fs) for _, fs in groups)
    if not fmt.numbered and any(len(fs) > 1 for _, fs in groups):
        name, fs = next(g for g in groups if len(g[1]) > 1)
        raise AuditError(f"{where}: {fmt.name} paths carry no time order ({len(fs)} frames in {name}): give --poses "
                         f"as a .json list of {{\"frame\": <sample token>, \"pose\": <4x4>}} in time order")
    if len(poses) == n:
        it = iter(poses)
        return [AuditSequence(name, tuple(fs), tuple(next(it) for _ in fs)) for name, fs in groups]
    if fmt.numbered and len(poses) > n and len(groups) == 1:
        name, fs = groups[0]
        return [AuditSequence(name, tuple(fs), tuple(_by_frame_number(fmt, fs, poses, where)))]
    hint = "one pose per frame, in the order the files are listed"
    if fmt.numbered:
        hint += (" (or, for one sequence, one pose per scan picked by the file's frame number: "
                 f"{_FIVE}; with several sequences use the keyed .json form)")
    raise AuditError(f"{where}: {len(poses)} poses for {n} {fmt.name} frames: give {hint}")


def _keyed(fmt: DatasetFormat, groups: list[tuple[str, list[Path]]], inputs: Sequence[InputFile],
           keyed: KeyedPoses, where: str) -> tuple[list[AuditSequence], int]:
    """Frames ordered by the keyed poses; returns the sequences and how many entries matched no file."""
    roots = {os.path.normcase(os.path.abspath(i.path)): i.root for i in inputs}
    names: dict[str, list[Path]] = {}  # every name a frame answers to -> its files
    for _, fs in groups:
        for f in fs:
            root = roots.get(os.path.normcase(os.path.abspath(f)), f)
            keys = {fmt.frame_token(f), f.as_posix(), str(f)}
            if root != f:
                keys.add(f.relative_to(root).as_posix())
            for k in keys:
                names.setdefault(k, []).append(f)
    posed: dict[Path, np.ndarray] = {}
    order: dict[Path, int] = {}
    unmatched = 0
    for i, (key, pose) in enumerate(zip(keyed.frames, keyed.poses)):
        hits = list(dict.fromkeys(names.get(key, [])))  # one file may answer to a key twice
        if not hits:
            unmatched += 1
            continue
        if len(hits) > 1:
            raise AuditError(f"{where}: frame {key!r} names {len(hits)} files ({hits[0]}, {hits[1]}, ...): "
                             f"give its path relative to PATH instead")
        if hits[0] in posed:
            raise AuditError(f"{where}: {hits[0]} has two poses (frames {keyed.frames[order[hits[0]]]!r} and {key!r})")
        posed[hits[0]], order[hits[0]] = pose, i
    if not posed:
        example = next(iter(groups))[1][0]
        raise AuditError(f"{where}: none of its {len(keyed.frames)} frames names an audited {fmt.name} file; "
                         f"\"frame\" is the sample token ({fmt.frame_token(example)!r}) or the path relative to PATH")
    out = []
    for name, fs in groups:
        timed = sorted((f for f in fs if f in posed), key=order.__getitem__)
        rest = [f for f in fs if f not in posed]
        out.append(AuditSequence(name, tuple(timed + rest), tuple([posed[f] for f in timed] + [None] * len(rest))))
    return out, unmatched


def plan_sequences(fmt: DatasetFormat, inputs: Sequence[InputFile], poses: np.ndarray | KeyedPoses | None = None,
                   where: str = "--poses") -> tuple[list[AuditSequence], int]:
    """The audit's sequences, each frame with its pose (module docstring); returns them and the
    number of keyed pose entries that name no audited file."""
    groups = group_sequences(fmt, [i.path for i in inputs])
    if poses is None:
        return [AuditSequence(name, tuple(fs)) for name, fs in groups], 0
    if isinstance(poses, KeyedPoses):
        return _keyed(fmt, groups, inputs, poses, where)
    return _ordered(fmt, groups, poses, where), 0


# -- the audit ---------------------------------------------------------------------------------------
@dataclass
class AuditResult:
    """Scores of one audited set of frames; counts indexed by internal id."""

    fmt: DatasetFormat
    frames: list[dict] = field(default_factory=list)  # path, sequence, s_sc, occupied, isolated, pose
    pairs: list[dict] = field(default_factory=list)  # t, t1 (frame indices), sequence, s_tc, intersection, union
    sequences: int = 0
    without_pose: int = 0  # frames left out of s_tc for want of a pose (keyed poses)
    poses_unmatched: int = 0  # keyed pose entries naming no audited file
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
            "sequences": self.sequences,
            "pairs": len(self.pairs),
            "frames_without_pose": None if t is None else self.without_pose,
            "poses_unmatched": None if t is None else self.poses_unmatched,
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


def audit(fmt: DatasetFormat, sequences: Sequence[AuditSequence]) -> AuditResult:
    """s_sc per frame and over all frames; where the sequences carry poses, s_tc per pair of
    consecutive frames with a pose **within** one sequence, and over all pairs (counts summed over
    the sequences). Frames are read and scored one at a time (two in memory)."""
    from carlaocc.stages.metrics import (column_ranges, sequence_continuity, sequence_temporal, spatial_continuity_counts,
                                static_table, temporal_consistency_counts)

    static = static_table(fmt.dynamic)
    has_poses = any(s.poses is not None for s in sequences)
    result = AuditResult(fmt, sequences=len(sequences))
    counts, pair_counts = [], []
    for seq in sequences:
        poses = seq.poses if seq.poses is not None else (None,) * len(seq.files)
        if len(poses) != len(seq.files):
            raise AuditError(f"{seq.name}: {len(poses)} poses for {len(seq.files)} frames")
        prev: tuple[int, AuditFrame, np.ndarray, tuple] | None = None  # the last frame with a pose
        for path, pose in zip(seq.files, poses):
            frame = read_frame(fmt, path)
            t = len(result.frames)
            c = spatial_continuity_counts(frame.semantic)
            counts.append(c)
            result.frames.append({"path": frame.path, "sequence": seq.name, "s_sc": _nan_to_none(c.score),
                                  "occupied": int(c.occupied[1:].sum()), "isolated": int(c.isolated[1:].sum()),
                                  "pose": pose is not None})
            if pose is None:
                result.without_pose += has_poses
                continue
            ranges = column_ranges(frame.semantic)  # serves both pairs of the frame
            if prev is not None:
                t0, f0, p0, ranges0 = prev
                use_mask = f0.mask is not None and frame.mask is not None
                tc = temporal_consistency_counts(
                    f0.semantic, frame.semantic, p0, pose, f0.voxel_size, f0.origin,
                    mask_t=f0.mask if use_mask else None, mask_t1=frame.mask if use_mask else None,
                    static=static, voxel_size_t1=frame.voxel_size, origin_t1=frame.origin,
                    ranges_t=ranges0, ranges_t1=ranges)
                pair_counts.append(tc)
                result.pairs.append({"t": t0, "t1": t, "sequence": seq.name, "s_tc": _nan_to_none(tc.score),
                                     "intersection": tc.total_intersection, "union": tc.total_union})
            prev = (t, frame, pose, ranges)
    result.continuity = sequence_continuity(counts)
    if has_poses:
        result.temporal = sequence_temporal(pair_counts)
    return result


def _fmt(v: float | None, digits: int = 4) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def format_table(result: AuditResult, per_frame: bool = False) -> str:
    """The paper's Table 4 columns (dataset, frames, s_sc, s_tc) plus the voxel counts, and a line
    saying what s_tc was computed over."""
    c = result.continuity
    lines = []
    if per_frame:
        lines.append(f"{'frame':>6}  {'s_sc':>7}  {'occupied':>12}  {'isolated':>10}  {'s_tc (t, next)':>14}  path")
        tc = {p["t"]: p["s_tc"] for p in result.pairs}
        for t, f in enumerate(result.frames):
            lines.append(f"{t:>6}  {_fmt(f['s_sc']):>7}  {f['occupied']:>12,}  {f['isolated']:>10,}  "
                         f"{_fmt(tc.get(t)):>14}  {f['path']}")
        lines.append("")
    lines.append(f"{'dataset':<16} {'frames':>7} {'s_sc':>7} {'s_tc':>7} {'occupied':>14} {'isolated':>12}")
    lines.append(f"{result.fmt.dataset:<16} {len(result.frames):>7} {_fmt(result.s_sc):>7} {_fmt(result.s_tc):>7} "
                 f"{int(c.occupied[1:].sum()):>14,} {int(c.isolated[1:].sum()):>12,}")
    if result.temporal is not None:
        note = f"s_tc over {len(result.pairs)} pairs of consecutive frames within {result.sequences} sequence(s)"
        if result.without_pose:
            note += f"; {result.without_pose} frame(s) without a pose left out"
        if result.poses_unmatched:
            note += f"; {result.poses_unmatched} pose(s) naming no audited file ignored"
        lines.append(note)
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
    inputs = collect_inputs(spec, paths)
    pose_spec = load_poses(poses) if poses is not None else None
    if calib is not None:
        if pose_spec is None:
            raise AuditError("--calib converts --poses from camera 0 to the LiDAR: give --poses too")
        tr = load_kitti_calib(calib)
        if isinstance(pose_spec, KeyedPoses):
            pose_spec = KeyedPoses(pose_spec.frames, np.linalg.inv(tr) @ pose_spec.poses @ tr)
        else:
            pose_spec = np.linalg.inv(tr) @ pose_spec @ tr
    sequences, unmatched = plan_sequences(spec, inputs, pose_spec, str(poses))
    result = audit(spec, sequences)
    result.poses_unmatched = unmatched
    if json_out is not None:
        out = Path(json_out)
        try:
            atomic_write(out, lambda fh: fh.write(json.dumps(result.to_json(), indent=1).encode()))
        except OSError as exc:
            raise AuditError(f"cannot write {out}: {exc.strerror or exc}") from None
    return result, format_table(result, per_frame)


def audit_cli(
    fmt: Annotated[str, typer.Argument(metavar="FORMAT", help=f"one of: {', '.join(FORMATS)}")],
    paths: Annotated[list[str], typer.Argument(metavar="PATH...", help="files of the format or directories "
                                               "(searched recursively, sorted by path)")],
    poses: Annotated[Optional[str], typer.Option("--poses", help="grid-frame-to-world 4x4 poses; enables s_tc. "
                                                 "Keyed: .json list of {\"frame\": sample token or path relative "
                                                 "to PATH, \"pose\": 4x4 or 16/12 numbers} in time order (needed "
                                                 "for occ3d scenes of several frames). Or one pose per frame in the "
                                                 "order the files are listed: .npy (N,4,4)/(N,3,4), .json, or text "
                                                 "with 12/16 numbers a line; a longer list for one numbered "
                                                 "sequence is indexed by frame number (KITTI poses.txt: one pose "
                                                 "per scan, SemanticKITTI voxels every 5th scan)")] = None,
    calib: Annotated[Optional[str], typer.Option("--calib", help="KITTI calib.txt: turn camera-0 --poses into "
                                                 "LiDAR poses with its Tr")] = None,
    json_out: Annotated[Optional[str], typer.Option("--json", help="write the scores (per frame, pair, class) "
                                                    "as JSON here")] = None,
    per_frame: Annotated[bool, typer.Option("--per-frame", help="print a row per frame too")] = False,
) -> None:
    """Quality scores of another dataset: spatial continuity s_sc, and temporal consistency s_tc
    with --poses (paper section 4.2, Table 4). Formats: occ3d, semantickitti, surroundocc,
    carlaocc-npz.

    s_tc pairs consecutive frames only within one sequence and sums the counts over sequences. A
    sequence is: occ3d, the scene directory (gts/SCENE/TOKEN/labels.npz); semantickitti, the
    voxels directory; surroundocc and carlaocc-npz, the file's directory. In a sequence, files
    named by frame numbers (semantickitti, surroundocc, carlaocc-npz) are in numeric order; occ3d
    sample tokens carry no time order, so its frames take the order of the keyed --poses list.
    Frames without a keyed pose are left out of s_tc (the summary line counts them)."""
    try:
        _, table = audit_command(fmt, paths, poses, calib, json_out, per_frame)
    except AuditError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(table)
