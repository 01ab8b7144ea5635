"""Pose files of audited datasets, and the sequences their frames form with those poses.

:func:`load_poses` reads grid-frame-to-world 4x4 poses (a pose is a 4x4 or 3x4 matrix, or 16 or
12 numbers row-major) in one of two forms:

* **Keyed** (:class:`KeyedPoses`): a ``.json`` list of ``{"frame": F, "pose": [...]}`` in **time
  order** (or ``{"poses": [that list]}``). ``F`` is the sample token (occ3d: the name of the
  directory holding ``labels.npz``; other formats: the file name without its ending, e.g.
  ``000005``), or the file's path relative to the path argument it was found under
  (``scene-0001/0b22/labels.npz``), or the path as listed.
* **One pose per frame in the order the files are listed** (:func:`carlaocc.catalog.formats.layout.group_sequences`):
  ``.npy`` of shape (N, 4, 4), (N, 3, 4), (N, 16) or (N, 12); ``.json`` a list of such matrices
  or ``{"poses": [...]}``; any other file is text with one pose per line, 12 (3x4, KITTI
  ``poses.txt``) or 16 (4x4) numbers row-major (blank and ``#`` lines skipped).

KITTI's ``poses.txt`` holds camera-0 poses: :func:`load_kitti_calib` reads the ``Tr`` line of its
``calib.txt`` (velodyne to camera 0), with which the caller turns them into LiDAR poses
``inv(Tr) @ P @ Tr``.

:func:`plan_sequences` gives each frame of each sequence its pose (:class:`PosedSequence`):

* keyed: the frames of each sequence are ordered as the list orders them; frames without an entry
  come last without a pose; entries naming no audited file are counted (at least one must match);
* one per frame: refused for occ3d when a scene has more than one frame (no time order: use the
  keyed form). For formats whose file names are frame numbers (semantickitti, surroundocc,
  carlaocc-npz) a list **longer** than the frames of a single sequence is indexed by the frame
  number: frame ``000005`` takes pose 5. That is KITTI's ``poses.txt``, one pose per LiDAR scan,
  while SemanticKITTI's voxel labels exist only for every 5th scan (000000, 000005, ...).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import DatasetInputError
from carlaocc.catalog.formats.layout import DatasetFormat, InputFile, group_sequences

__all__ = ["KeyedPoses", "PosedSequence", "load_kitti_calib", "load_poses", "plan_sequences"]


def _as_poses(values, where: str) -> np.ndarray:
    """(N, 4, 4) float64 from (N, 4, 4), (N, 3, 4), (N, 16) or (N, 12) values."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetInputError(f"{where}: poses are not numbers ({exc})") from None
    if a.ndim == 2 and a.shape[1] in (12, 16):
        a = a.reshape(len(a), a.shape[1] // 4, 4)
    if a.ndim != 3 or a.shape[1:] not in ((3, 4), (4, 4)):
        raise DatasetInputError(f"{where}: expected N poses of 3x4 or 4x4 (12 or 16 numbers), got shape {a.shape}")
    if a.shape[1] == 3:
        a = np.concatenate([a, np.broadcast_to([[[0.0, 0.0, 0.0, 1.0]]], (len(a), 1, 4))], axis=1)
    if not np.isfinite(a).all():
        raise DatasetInputError(f"{where}: poses must be finite")
    bad = np.flatnonzero(~np.isclose(np.linalg.det(a[:, :3, :3]), 1.0, atol=1e-3))
    if bad.size:
        det = np.linalg.det(a[bad[0], :3, :3])
        raise DatasetInputError(f"{where}: pose {int(bad[0])} has no rotation part (det {det:.4g})")
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
            raise DatasetInputError(f"{where}: entry {n} must be {{\"frame\": ..., \"pose\": ...}}, got {str(e)[:60]}")
        if not isinstance(e["frame"], str) or not e["frame"]:
            raise DatasetInputError(f"{where}: entry {n}: \"frame\" must be a sample token or a path (a string), "
                                    f"got {e['frame']!r}")
        try:
            values = np.asarray(e["pose"], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            values = np.zeros(0)
        if values.size not in (12, 16):
            raise DatasetInputError(f"{where}: entry {n} ({e['frame']}): a pose is a 4x4 or 3x4 matrix or 16 or 12 "
                                    f"numbers")
        if e["frame"] in seen:
            raise DatasetInputError(f"{where}: frame {e['frame']!r} is listed more than once")
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
        raise DatasetInputError(f"{p}: cannot read poses ({exc})") from None
    if p.suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DatasetInputError(f"{p}: not JSON ({exc})") from None
        if isinstance(data, dict):
            if "poses" not in data:
                raise DatasetInputError(f"{p}: a JSON object must hold the poses under \"poses\"")
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
            raise DatasetInputError(f"{p}:{n}: not numbers: {line[:60]!r}") from None
        if len(values) not in (12, 16):
            raise DatasetInputError(f"{p}:{n}: a pose is 12 (3x4) or 16 (4x4) numbers, got {len(values)}")
        rows.append(values if len(values) == 16 else values + [0.0, 0.0, 0.0, 1.0])
    if not rows:
        raise DatasetInputError(f"{p}: no poses")
    return _as_poses(rows, str(p))


def load_kitti_calib(path: str | os.PathLike) -> np.ndarray:
    """The 4x4 velodyne-to-camera-0 transform from a KITTI ``calib.txt`` (its ``Tr:`` line)."""
    p = Path(path)
    try:
        lines = p.read_text().splitlines()
    except OSError as exc:
        raise DatasetInputError(f"{p}: cannot read calibration ({exc})") from None
    for line in lines:
        key, _, rest = line.partition(":")
        if key.strip() == "Tr":
            return _as_poses([rest.split()], f"{p} (Tr)")[0]
    raise DatasetInputError(f"{p}: no 'Tr:' line (velodyne to camera 0)")


@dataclass(frozen=True)
class PosedSequence:
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
            raise DatasetInputError(f"{where}: {len(poses)} poses for fewer {fmt.name} frames, and {f.name} has no "
                                    f"frame number to pick its pose by")
        if k >= len(poses):
            raise DatasetInputError(f"{where}: {len(poses)} poses, none for frame {k} ({f}); {_FIVE}: give that "
                                    f"sequence's full poses.txt")
        out.append(poses[k])
    return out


def _ordered(fmt: DatasetFormat, groups: list[tuple[str, list[Path]]], poses: np.ndarray,
             where: str) -> list[PosedSequence]:
    """Poses given one per listed frame (or, for numbered files of one sequence, one per scan)."""
    n = sum(len(fs) for _, fs in groups)
    if not fmt.numbered and any(len(fs) > 1 for _, fs in groups):
        name, fs = next(g for g in groups if len(g[1]) > 1)
        raise DatasetInputError(f"{where}: {fmt.name} paths carry no time order ({len(fs)} frames in {name}): give "
                                f"--poses as a .json list of {{\"frame\": <sample token>, \"pose\": <4x4>}} in time "
                                f"order")
    if len(poses) == n:
        it = iter(poses)
        return [PosedSequence(name, tuple(fs), tuple(next(it) for _ in fs)) for name, fs in groups]
    if fmt.numbered and len(poses) > n and len(groups) == 1:
        name, fs = groups[0]
        return [PosedSequence(name, tuple(fs), tuple(_by_frame_number(fmt, fs, poses, where)))]
    hint = "one pose per frame, in the order the files are listed"
    if fmt.numbered:
        hint += (" (or, for one sequence, one pose per scan picked by the file's frame number: "
                 f"{_FIVE}; with several sequences use the keyed .json form)")
    raise DatasetInputError(f"{where}: {len(poses)} poses for {n} {fmt.name} frames: give {hint}")


def _keyed(fmt: DatasetFormat, groups: list[tuple[str, list[Path]]], inputs: Sequence[InputFile],
           keyed: KeyedPoses, where: str) -> tuple[list[PosedSequence], int]:
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
            raise DatasetInputError(f"{where}: frame {key!r} names {len(hits)} files ({hits[0]}, {hits[1]}, ...): "
                                    f"give its path relative to PATH instead")
        if hits[0] in posed:
            first = keyed.frames[order[hits[0]]]
            raise DatasetInputError(f"{where}: {hits[0]} has two poses (frames {first!r} and {key!r})")
        posed[hits[0]], order[hits[0]] = pose, i
    if not posed:
        example = next(iter(groups))[1][0]
        raise DatasetInputError(f"{where}: none of its {len(keyed.frames)} frames names an audited {fmt.name} file; "
                                f"\"frame\" is the sample token ({fmt.frame_token(example)!r}) or the path relative "
                                f"to PATH")
    out = []
    for name, fs in groups:
        timed = sorted((f for f in fs if f in posed), key=order.__getitem__)
        rest = [f for f in fs if f not in posed]
        out.append(PosedSequence(name, tuple(timed + rest), tuple([posed[f] for f in timed] + [None] * len(rest))))
    return out, unmatched


def plan_sequences(fmt: DatasetFormat, inputs: Sequence[InputFile], poses: np.ndarray | KeyedPoses | None = None,
                   where: str = "--poses") -> tuple[list[PosedSequence], int]:
    """The audit's sequences, each frame with its pose (module docstring); returns them and the
    number of keyed pose entries that name no audited file."""
    groups = group_sequences(fmt, [i.path for i in inputs])
    if poses is None:
        return [PosedSequence(name, tuple(fs)) for name, fs in groups], 0
    if isinstance(poses, KeyedPoses):
        return _keyed(fmt, groups, inputs, poses, where)
    return _ordered(fmt, groups, poses, where), 0
