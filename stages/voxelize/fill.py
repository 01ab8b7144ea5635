"""Which meshes are filled, and how: one rule for the pipeline and the standalone voxelizer.

Fill modes
----------
* ``"surface"``: nothing is filled; every mesh is its surface voxels.
* ``"solid"``: every mesh is filled.
* ``"auto"`` (the default): the per-class rule below.

The per-class rule (``auto``)
-----------------------------
*Volumetric* classes are filled: the road users (vehicles, people), buildings and the other
classes whose objects are solids -- Wall, Pole, TrafficLight, TrafficSign, Static and Dynamic
props, Rock -- whichever of them the label table makes things. *Thin or open* classes stay surfaces: Road, Sidewalk, RoadLine, Terrain, Ground,
Water, RailTrack, Bridge (ground-like meshes cut to the region), Fence and GuardRail (thin
structures, often single sheets), Other (unknown geometry) and Vegetation: a tree's crown and
trunk share the class, and a crown is foliage, not a solid -- so vegetation stays a surface
except the parts an asset marks as a trunk (part name containing ``trunk``, as the procedural
trees and most tree models name them).

How a filled mesh is filled
---------------------------
A watertight mesh (each edge shared by exactly two faces) by column parity, exact and fast
(:func:`carlaocc.stages.voxelize.kernels.fill_interior`); any other mesh by generalized winding
numbers (:mod:`carlaocc.stages.voxelize.winding`), which close cracks, open floors, open wheel
arches and open bases without leaking out of the mesh's bounding box.
"""

from __future__ import annotations

from typing import Literal

from carlaocc.schemas import taxonomy

__all__ = ["FillMode", "FILL_MODES", "FillMethod", "VOLUMETRIC_CLASSES", "fills", "fill_method", "is_trunk",
           "check_fill_mode"]

FillMode = Literal["auto", "surface", "solid"]
FILL_MODES: tuple[str, ...] = ("auto", "surface", "solid")
FillMethod = Literal["surface", "parity", "winding"]

# Solid objects, whatever label table says which of them carry instance ids: the road users,
# buildings, and the closed static structures and props.
_VOLUMETRIC = ("Pedestrian", "Rider", "Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle", "Building",
               "Wall", "Pole", "TrafficLight", "TrafficSign", "Static", "Dynamic", "Rock")
VOLUMETRIC_CLASSES: frozenset[int] = frozenset(taxonomy.by_name(n).id for n in _VOLUMETRIC)
"""Semantic ids filled under ``auto`` (the same under every label table)."""
_VEGETATION = taxonomy.by_name("Vegetation").id


def check_fill_mode(fill: str) -> None:
    """Raise ValueError naming the allowed modes unless ``fill`` is one of them."""
    if fill not in FILL_MODES:
        raise ValueError(f"fill mode must be one of {', '.join(FILL_MODES)}, got {fill!r}")


def is_trunk(part: str) -> bool:
    """Whether an asset part is marked as a tree trunk (its name contains ``trunk``)."""
    return "trunk" in part.lower()


def fills(semantic_id: int, part: str = "", fill: str = "auto") -> bool:
    """Whether a mesh of class ``semantic_id`` (asset part ``part``) is filled under ``fill``."""
    check_fill_mode(fill)
    if fill == "surface":
        return False
    if fill == "solid":
        return True
    if int(semantic_id) == _VEGETATION:
        return is_trunk(part)
    return int(semantic_id) in VOLUMETRIC_CLASSES


def fill_method(filled: bool, watertight: bool) -> FillMethod:
    """How a mesh is written: ``surface`` (not filled), ``parity`` (filled, watertight) or
    ``winding`` (filled, open)."""
    if not filled:
        return "surface"
    return "parity" if watertight else "winding"
