"""How a dataset of one external format lies on disk: which files are its frames, how they group
into sequences, and how one frame reads into a label grid for the quality scores.

Each format module describes its layout with a :class:`DatasetFormat` (the registry is
:data:`carlaocc.catalog.formats.FORMATS`):

==============  =========================  ======================================  =====================
format          files collected            grid (origin m, voxel m), frame          visibility mask
==============  =========================  ======================================  =====================
occ3d           ``labels.npz``             (-40, -40, -1), 0.4, ego                 ``mask_camera``
semantickitti   ``<stem>.label`` (+ .bin,  (0, -25.6, -2), 0.2, LiDAR (velodyne)    not ``.invalid``
                .invalid, .occluded)
surroundocc     ``*.npy`` (N, 4) rows      (-50, -50, -5), 0.5, LiDAR               none
carlaocc-npz    ``*.npz``                  from each file, LiDAR                    none
==============  =========================  ======================================  =====================

A frame reads into a :class:`LabelGrid`: uint8 labels where 0 is free (the quality scores'
convention) and every dataset class keeps its own id (Occ3D: ids 0-16 -> 1-17, free 17 -> 0;
SemanticKITTI: the 20 learning ids, 0 = empty; SurroundOcc: label + 1, a missing row = free,
label 0 "noise" counted as a class; CarlaOcc: its ids); :attr:`DatasetFormat.to_dataset_id` maps
back to the dataset's ids and names. Labels are as published (SemanticKITTI's invalid voxels
included: the mask is separate). Dynamic classes (:attr:`DatasetFormat.dynamic`): the road users
(Occ3D/SurroundOcc bicycle, bus, car, construction_vehicle, motorcycle, pedestrian, trailer,
truck; SemanticKITTI car ... motorcyclist; CarlaOcc the taxonomy's dynamic classes). An occ3d file
must be Occ3D-nuScenes' (200, 200, 16) grid with ids 0..17 (the geometry above is assumed):
another shape or a larger id is refused, naming the file.

Paths and sequences (:func:`collect_inputs`, :func:`group_sequences`): each path is a file of the
format or a directory searched recursively (a file found twice is listed once). The files are
split into **sequences**:

* occ3d: the scene directory, ``gts/<scene>/<sample_token>/labels.npz`` (the grandparent of the
  file). Sample tokens are random hex: a path carries **no time order**;
* semantickitti: the ``voxels`` directory of one sequence (the file's parent);
* surroundocc, carlaocc-npz: the file's parent directory.

Sequences are listed in the order of their first file (directories sorted by path, path
arguments in their order). Within a sequence the files of semantickitti, surroundocc and
carlaocc-npz are sorted numerically by their frame number (the file name without its ending,
``000005.label`` -> 5) when every name is a number, else kept in path order; occ3d files are
listed in path order.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import DatasetInputError, FormatError

__all__ = ["DatasetFormat", "InputFile", "LabelGrid", "collect_inputs", "grid_origin", "group_sequences", "read_frame"]


@dataclass(frozen=True)
class LabelGrid:
    """One frame, ready for the quality scores: uint8 labels ``[x, y, z]`` (0 = free, else the
    dataset's class, see the module docstring), an optional visibility mask (True = observed) and
    the grid geometry (voxel size and origin of voxel (0, 0, 0) in metres, in the dataset's grid
    frame)."""

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
    read: Callable[[Path], LabelGrid]
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
        """A frame's short name for keyed poses: the format's ``token`` (occ3d: the sample token)
        or the file's stem."""
        return self.token(path) if self.token is not None else self.stem(path)


def grid_origin(rng: Sequence[float]) -> tuple[float, float, float]:
    """The minimum corner (metres) of a format's ``(x_min, y_min, z_min, x_max, y_max, z_max)`` range."""
    return (float(rng[0]), float(rng[1]), float(rng[2]))


@dataclass(frozen=True)
class InputFile:
    """One collected file and the path argument it was found under (for keyed poses)."""

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
                raise DatasetInputError(f"no {fmt.name} files (*{fmt.suffix}) under {p}")
        else:
            raise DatasetInputError(f"{p}: no such file or directory")
        for q in found:
            key = os.path.normcase(os.path.abspath(q))
            if key not in seen:  # a file under two path arguments is one frame
                seen.add(key)
                out.append(InputFile(q, p))
    if not out:
        raise DatasetInputError("no input paths given")
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


def read_frame(fmt: DatasetFormat, path: Path) -> LabelGrid:
    """Read one file; an unreadable one raises :class:`DatasetInputError` naming it once (a
    reader's message that names it, or another file of its scan, is not prefixed)."""
    try:
        return fmt.read(path)
    except (FormatError, OSError, ValueError) as exc:
        msg = str(exc)
        named = str(path) in msg or str(path.with_name(fmt.stem(path))) in msg
        raise DatasetInputError(msg if named else f"{path}: {msg}") from None
