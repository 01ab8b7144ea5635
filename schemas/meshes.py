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
    # what the material looks like (cameras' RGB): its base colour RGBA 0-255 (None: the source
    # gives none), its base colour texture as an (H, W, 3) uint8 image with texture coordinates
    # per triangle corner (M, 3, 2) float32 (u right, v up from the image's bottom-left corner,
    # repeating outside [0, 1]); None when the part has no texture or its image is missing
    color: tuple[int, int, int, int] | None = None
    corner_uv: np.ndarray | None = None
    image: np.ndarray | None = None


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
    # the base colour texture (H, W, 3) uint8 and its coordinates per triangle corner (M, 3, 2)
    # float32 (u right, v up from the bottom-left corner, repeating): both or neither
    corner_uv: np.ndarray | None = None
    image: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int64))
        _check_texture(self.name, len(self.faces), self.corner_uv, self.image)
        if self.corner_uv is not None:
            object.__setattr__(self, "corner_uv", np.ascontiguousarray(self.corner_uv, dtype=np.float32))


def _check_texture(name: str, n_faces: int, corner_uv, image) -> None:
    """A texture comes with coordinates for every triangle corner, and the other way round."""
    if (corner_uv is None) != (image is None):
        raise ValueError(f"part {name!r}: a texture needs both its image and its corner coordinates")
    if corner_uv is not None:
        if np.shape(corner_uv) != (n_faces, 3, 2):
            raise ValueError(f"part {name!r}: corner coordinates have shape {np.shape(corner_uv)}, "
                             f"expected ({n_faces}, 3, 2)")
        if np.ndim(image) != 3 or np.shape(image)[2] != 3 or np.asarray(image).dtype != np.uint8:
            raise ValueError(f"part {name!r}: a texture image is (H, W, 3) uint8")


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
    corner_uv: np.ndarray | None = None  # (M, 3, 2) float32, the part's texture coordinates
    image: np.ndarray | None = None  # (H, W, 3) uint8, the part's base colour texture

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int64))
        _check_texture(self.name, len(self.faces), self.corner_uv, self.image)
