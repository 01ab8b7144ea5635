"""Occupancy-and-flow layouts: OpenOcc v2's ``<scene>/<token>/labels.npz`` (``semantics``,
``instances``, ``flow``) and UniOcc's ``<scene>/<frame>.npz`` (object arrays, read with
``allow_pickle=True`` as its loader does) with ``scene_infos.pkl``
(``../shared/reference/training-formats.md`` sections 2 and 3)."""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import atomic_write


def npz_bytes(arrays: dict) -> bytes:
    """``np.savez_compressed`` of ``arrays`` as bytes."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def save_openocc_v2(path: Path, semantics: np.ndarray, instances: np.ndarray, flow: np.ndarray) -> None:
    """One OpenOcc v2 frame: ``semantics`` uint8, ``instances`` uint32, ``flow`` (..., 2) float32 m/s."""
    body = npz_bytes({"semantics": semantics.astype(np.uint8), "instances": instances, "flow": flow})
    atomic_write(path, lambda fh: fh.write(body))


def save_uniocc_frame(path: Path, arrays: dict) -> None:
    """One UniOcc frame (its keys as given; lists of dicts become object arrays)."""
    body = npz_bytes({k: np.array(v, dtype=object) if isinstance(v, list) else v for k, v in arrays.items()})
    atomic_write(path, lambda fh: fh.write(body))


def save_scene_infos(path: Path, scene_infos: list[dict]) -> None:
    """UniOcc's ``scene_infos.pkl``: ``[{"scene_name", "occ_in_scene_paths"}, ...]`` (protocol 4)."""
    atomic_write(path, lambda fh: pickle.dump(scene_infos, fh, protocol=4))
