"""What makes a source asset unusable before any geometry work, and how that is said.

:class:`Rejection` (a reason for the quarantine table and a hint to fix it) is what every step
of ``carlaocc.stages.ingest.standardize`` returns for bad data; bad data never raises. The checks here are
the first two steps: the asset's class (:func:`check_category`) and each part's arrays
(:func:`check_arrays`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import SourceAsset, SourcePart


@dataclass(frozen=True)
class Rejection:
    """Why an asset is quarantined, and how to fix it."""

    reason: str
    hint: str


def check_category(raw: SourceAsset) -> taxonomy.SemanticClass | Rejection:
    """The asset's taxonomy class, or why it has none (no category, unknown name, the empty
    label): categories are never guessed."""
    if raw.category is None or not str(raw.category).strip():
        return Rejection("no category", "the source gives no class for this object: add it to the "
                         "source's category map (categories are never guessed)")
    try:
        cls = taxonomy.by_name(str(raw.category))
    except KeyError:
        valid = ", ".join(c.name for c in taxonomy.CLASSES if c.id != 0)
        return Rejection(f"unknown category '{raw.category}'",
                         f"map it to one of the taxonomy classes: {valid}")
    if cls.id == 0:
        return Rejection("no category", f"class {raw.category!r} is the empty label (id 0): map the "
                         "object to a real class")
    return cls


def check_arrays(k: int, part: SourcePart) -> tuple[np.ndarray, np.ndarray] | Rejection:
    """The part's arrays as float64 (N, 3) and int64 (M, 3), or why they cannot be used."""
    name = part.name or f"part {k}"
    try:
        v = np.asarray(part.vertices, dtype=np.float64)
    except (TypeError, ValueError):
        return Rejection("bad vertices", f"{name}: vertices must be an (N, 3) array of numbers")
    f = np.asarray(part.faces)
    if v.size == 0:
        v = v.reshape(0, 3)
    if f.size == 0:
        f = f.reshape(0, 3)
    if v.ndim != 2 or v.shape[1] != 3:
        return Rejection("bad vertices", f"{name}: vertices have shape {v.shape}, expected (N, 3)")
    if f.ndim != 2 or f.shape[1] != 3:
        return Rejection("not triangles", f"{name}: faces have shape {f.shape}, expected (M, 3): "
                         "triangulate polygons in the source adapter")
    if not np.issubdtype(f.dtype, np.integer):
        ok = np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f))
        if not ok:
            return Rejection("not triangles", f"{name}: face indices must be integers, got {f.dtype}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        bad = int(np.count_nonzero((f < 0) | (f >= len(v))))
        return Rejection("face index out of range",
                         f"{name}: {bad} face indices outside 0..{len(v) - 1} ({len(v)} vertices): "
                         "the source file is corrupt or its index buffers were mis-read")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(v), axis=1)))
        return Rejection("non-finite vertices",
                         f"{name}: {bad} of {len(v)} vertices are NaN or infinite: repair or "
                         "re-export the mesh")
    return v, f
