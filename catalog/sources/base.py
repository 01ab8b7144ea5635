"""The one interface every mesh source adapter implements.

An adapter lists a source root as :class:`SourceItem` s (one per source object: a file, a model
folder, a CSV row, a scene object...) and reads one item into a :class:`SourceAsset`: triangle
parts in the SOURCE's own frame and units, with what the source declares about them (up and
forward axes, units, category, licence). Standardization (frame, units, cleaning, validation)
happens later, in ``stages.ingest.standardize``; adapters only read and describe.

A problem with one item raises :class:`SourceError` (reason + hint): the batch quarantines that
item and goes on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np

Axis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]
Units = Literal["m", "cm", "mm", "in", "unknown"]


class SourceError(Exception):
    """An item that cannot be ingested: ``reason`` (short, for the quarantine table) and ``hint``."""

    def __init__(self, reason: str, hint: str = ""):
        super().__init__(reason)
        self.reason = reason
        self.hint = hint


@dataclass(frozen=True)
class SourceItem:
    """One thing to ingest. ``key`` is unique within the source and stable (a relative path, a
    model id, a sha256...); ``files`` are the absolute paths whose bytes define it (their
    fingerprints decide whether a re-run re-ingests it); ``meta`` is JSON-able adapter data."""

    key: str
    files: tuple[str, ...]
    meta: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SourcePart:
    """A triangle sub-mesh in the source frame and units."""

    name: str
    vertices: np.ndarray  # (N, 3) float64, source frame and units
    faces: np.ndarray  # (M, 3) int64 triangles (adapters triangulate; non-indexed meshes indexed)
    material: str = "default"
    transparent: bool = False  # glTF alphaMode BLEND or alpha < 1; MTL d < 1 or Tr > 0
    texture: str = ""  # texture reference, kept by reference
    semantic_id: int | None = None  # part-level class when the source labels parts


@dataclass(frozen=True)
class SourceAsset:
    """One source object, read but not standardized."""

    source: str  # adapter kind: "folder", "shapenet", ...
    source_path: str  # what a user recognises: the file, or file#object
    licence: str  # "" when the source has none (quarantined where the source requires one)
    category: str | None  # taxonomy class name; None: no category (quarantined, never guessed)
    subclass: str
    parts: tuple[SourcePart, ...]
    up: Axis = "+z"  # the source's up axis
    forward: Axis = "+x"  # the source's forward axis
    units: Units = "unknown"  # declared units; "unknown": infer from the sub-class size range
    normalized: bool = False  # the source normalized its size (ShapeNet, MeshFleet): rescale
    target_length: float | None = None  # metres, when known (category map length_m, MeshFleet)
    licence_required: bool = False


class SourceAdapter(Protocol):
    """What every adapter offers."""

    kind: str

    def list_items(self, root: str) -> list[SourceItem]:
        """Every item under ``root``, sorted by key. Raises SourceError when the root itself is
        unusable (missing, not the expected layout)."""
        ...

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        """Read one item; raises SourceError for a bad item."""
        ...
