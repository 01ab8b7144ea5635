"""In-memory mesh contracts every layer shares: frozen dataclasses over numpy arrays.

Two sides of the ingest stage:

* **Source side** (what a catalog source adapter reads, before standardization):
  :class:`SourceAsset` made of :class:`SourcePart` s, in the SOURCE's own frame and units, with
  what the source declares about them (:data:`Axis` up and forward, :data:`Units`).
  ``carlaocc.catalog.sources`` adapters return it; ``carlaocc.stages.ingest.standardize`` accepts it.
* **Standardized side** (what every later stage consumes): :class:`MeshPart` s in the asset frame
  (metres, +X forward, +Y left, Z up, origin at the bottom centre of the asset's bounding box),
  grouped per asset as :class:`AssetGeometry`, and placed into one frame's panoptic scene as
  :class:`SceneMesh` (grid frame = LiDAR frame, metres).

Vertices are ``(N, 3)`` float64, faces ``(M, 3)`` int64 triangles indexing them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Axis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]
"""A signed coordinate axis of a source's frame (its declared up or forward)."""

Units = Literal["m", "cm", "mm", "in", "unknown"]
"""Length units a source can declare; ``"unknown"``: inferred from the sub-class's size range."""


# --------------------------------------------------------------------------------------------
# source side: read, not standardized
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SourcePart:
    """A triangle sub-mesh in the source frame and units."""

    name: str
    vertices: np.ndarray  # (N, 3) float64, source frame and units
    faces: np.ndarray  # (M, 3) int64 triangles (adapters triangulate; non-indexed meshes indexed)
    material: str = "default"
    transparent: bool = False  # glTF alphaMode BLEND or alpha < 1; MTL d < 1 or Tr > 0
    texture: str = ""  # texture reference, kept by reference
    semantic_id: int | None = None  # part-level class when the source labels parts; None: the asset's


@dataclass(frozen=True)
class SourceAsset:
    """One source object, read but not standardized, with what its source declares about frame,
    units and labels."""

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
    # what the source lacks but the geometry does not need (a missing material library or
    # texture file): standardization keeps the asset and records these in AssetRecord.notes
    notes: tuple[str, ...] = ()


# --------------------------------------------------------------------------------------------
# standardized side: asset frame, scene frame
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MeshPart:
    """A sub-mesh of an asset in the asset frame (+X forward, Z up, metres, origin at the bottom
    centre of the asset's bounding box), with its material and semantic class."""

    name: str
    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64
    semantic_id: int
    material: str = "default"
    transparent: bool = False
    color: tuple[int, int, int, int] = (200, 200, 200, 255)

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int64))


@dataclass(frozen=True)
class AssetGeometry:
    """The geometry of one asset (or town stuff mesh) as the scene composer consumes it:
    its parts in the asset frame and, per part, whether it is closed (watertight)."""

    asset_id: str
    parts: tuple[MeshPart, ...]
    part_closed: tuple[bool, ...]


@dataclass(frozen=True)
class SceneMesh:
    """A mesh of one frame's panoptic scene, in the grid's frame (LiDAR frame, metres).

    ``closed``: the mesh is watertight as given (a whole asset part; a part cut to a region is
    not). Whether it is filled is the voxelizer's fill rule (class, ``part``, fill mode): a filled
    closed mesh by column parity, a filled open one by winding numbers. ``instance_id`` is 0 for
    stuff. ``part`` is the asset part's name (``trunk`` marks a tree trunk).
    """

    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64
    semantic_id: int
    instance_id: int
    is_stuff: bool
    closed: bool
    name: str = field(default="")
    transparent: bool = False  # glass and other see-through parts (cameras see past them)
    asset_id: str = ""  # the ADMesh asset (or town stuff key) the mesh is a part of
    part: str = ""  # the asset part's name
    color: tuple[int, int, int] = (200, 200, 200)  # the part's base colour, RGB 0-255 (cameras' RGB)

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int64))
