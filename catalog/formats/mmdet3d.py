"""The OpenMMLab occupancy pipelines' info files (BEVDet / FlashOcc / SparseOcc read them):
``<prefix>_<split>.pkl`` (a pickled ``{"infos": [...], "metadata": {...}}``) with a JSON copy,
and the JPEG camera images their ``cams`` entries name."""

from __future__ import annotations

import io
import json
import pickle
from pathlib import Path

import numpy as np
from PIL import Image

from carlaocc.catalog.formats import atomic_write


def jpeg_bytes(image: np.ndarray) -> bytes:
    """(H, W, 3) uint8 RGB as JPEG bytes (quality 95)."""
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="JPEG", quality=95)
    return buf.getvalue()


def json_ready(obj):
    """An info tree with numpy arrays and scalars as lists and numbers (for the JSON copy)."""
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def save_infos(out: Path, name: str, doc: dict) -> int:
    """Write ``out/<name>.pkl`` (pickle protocol 4) and ``out/<name>.json``; returns 2."""
    atomic_write(Path(out) / f"{name}.pkl", lambda fh: pickle.dump(doc, fh, protocol=4))
    atomic_write(Path(out) / f"{name}.json", lambda fh: fh.write(json.dumps(json_ready(doc), indent=1).encode()))
    return 2

