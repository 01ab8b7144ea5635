"""Prediction and ground-truth files as ``carlaocc eval`` reads them, shared by the evaluation
commands and the viewer's ``--pred/--gt`` mode (one reader, one pairing rule).

* :func:`pair_files` pairs two files, or two directories by relative path without the suffix;
* :func:`load_arrays` reads every array of an ``.npz`` (or an ``.npy``) without pickles;
* :func:`load_occupancy` reads one occupancy file (``semantics`` [+ ``instances``], the masks, a
  one-array npz / npy, or a published CarlaOcc npz mapped into a label space).

Every problem raises :class:`InputError` naming the file (the CLI prints it as one line, exit 2).
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

__all__ = ["InputError", "load_arrays", "load_occupancy", "pair_files"]


class InputError(ValueError):
    """A bad input file or argument; the CLI prints it as one line and exits with code 2."""



def pair_files(pred: Path, gt: Path, suffixes: tuple[str, ...]) -> list[tuple[str, Path, Path]]:
    """``(key, pred_file, gt_file)`` for two files, or for two directories paired by relative path
    without suffix (files with other suffixes are not considered)."""
    for opt, p in (("--pred", pred), ("--gt", gt)):
        if not p.exists():
            raise InputError(f"{opt} {p} does not exist")
    if pred.is_file() and gt.is_file():
        return [(gt.stem, pred, gt)]
    if not (pred.is_dir() and gt.is_dir()):
        raise InputError(f"--pred {pred} and --gt {gt} must both be files or both be directories")

    def index(root: Path, opt: str) -> dict[str, Path]:
        out: dict[str, Path] = {}
        for f in sorted(root.rglob("*")):
            if f.is_file() and f.suffix.lower() in suffixes:
                key = f.relative_to(root).with_suffix("").as_posix()
                if key in out:
                    raise InputError(f"{opt}: {out[key]} and {f} both pair with {key!r}")
                out[key] = f
        return out

    p_files, g_files = index(pred, "--pred"), index(gt, "--gt")
    if not g_files:
        raise InputError(f"--gt {gt} holds no {' / '.join(suffixes)} files")
    for key in sorted(g_files):
        if key not in p_files:
            raise InputError(f"no prediction for {g_files[key]} (expected {pred / key}{g_files[key].suffix} or another of {', '.join(suffixes)})")
    for key in sorted(p_files):
        if key not in g_files:
            raise InputError(f"prediction {p_files[key]} has no ground truth under {gt}")
    return [(k, p_files[k], g_files[k]) for k in sorted(g_files)]


def load_arrays(path: Path, occupancy_ok: bool = False) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` (or ``{"": array}`` of an ``.npy``), no pickles; errors name the
    file. With ``occupancy_ok``, a CarlaOcc npz returns ``{"occupancy": None}`` unread."""
    try:
        loaded = np.load(path, allow_pickle=False)
        if isinstance(loaded, np.ndarray):
            return {"": loaded}
        with loaded as z:
            if occupancy_ok and "occupancy" in z.files:
                return {"occupancy": None}  # type: ignore[dict-item]
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


def load_occupancy(path: Path, lm, instances: bool) -> tuple[np.ndarray, np.ndarray | None, dict[str, np.ndarray]]:
    """``(semantics, instances or None, masks)`` of one occupancy file in ``lm``'s label space."""
    arrays = load_arrays(path, occupancy_ok=True)
    if "occupancy" in arrays:  # a published CarlaOcc npz: CarlaOcc ids, mapped into lm
        from carlaocc.catalog.formats import FormatError, load_carlaocc_npz

        try:
            frame = load_carlaocc_npz(path)
            return lm.convert_carlaocc(frame.semantic), frame.instance, {}
        except (FormatError, ValueError) as exc:
            raise InputError(f"{path}: {exc}") from exc
    if "semantics" in arrays:
        sem = arrays["semantics"]
    elif len(arrays) == 1:
        sem = next(iter(arrays.values()))
    else:
        raise InputError(f"{path}: no 'semantics' array (found {sorted(arrays)})")
    inst = None
    if instances:
        if "instances" not in arrays:
            raise InputError(f"{path}: no 'instances' array for panoptic scoring (found {sorted(arrays)})")
        inst = arrays["instances"]
        if inst.shape != sem.shape:
            raise InputError(f"{path}: instances {inst.shape} and semantics {sem.shape} differ in shape")
    for name, a in (("semantics", sem), ("instances", inst)):
        if a is not None and not np.issubdtype(a.dtype, np.integer):
            raise InputError(f"{path}: {name} must be integers, got {a.dtype}")
    masks = {k: arrays[k] for k in ("mask_camera", "mask_lidar") if k in arrays}
    return sem, inst, masks
