"""What standardization consumes: a source object read but not standardized.

The pipeline builds these from the catalog's source adapters (``catalog.sources``); the fields
mirror ``catalog.sources.base.SourceAsset`` so the compute here needs nothing from the catalog.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Axis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]
Units = Literal["m", "cm", "mm", "in", "unknown"]


@dataclass(frozen=True)
class RawPart:
    """A triangle sub-mesh in the source frame and units."""

    name: str
    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64
    material: str = "default"
    transparent: bool = False
    texture: str = ""
    semantic_id: int | None = None  # None: the asset's class


@dataclass(frozen=True)
class RawAsset:
    """A source object with what its source declares about frame, units and labels."""

    source: str
    source_path: str
    licence: str
    category: str | None
    subclass: str
    parts: tuple[RawPart, ...]
    up: Axis = "+z"
    forward: Axis = "+x"
    units: Units = "unknown"
    normalized: bool = False
    target_length: float | None = None
    licence_required: bool = False


@dataclass(frozen=True)
class Rejection:
    """Why an asset is quarantined, and how to fix it."""

    reason: str
    hint: str
