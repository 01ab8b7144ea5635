"""Where a voxelization's volume comes from: surface, fill, and hole handling.

For a set of meshes on a grid, three counts of voxels:

* ``surface``: the voxels of the surface-only voxelization (``fill="surface"``);
* ``filled``: the voxels the fill adds to them (occupied under the fill mode, free under
  ``surface``);
* ``from_holes``: the filled voxels a flood fill could not have found -- those connected to the
  grid's boundary through free voxels of the surface-only grid (6-connectivity), i.e. reached
  through a hole, a crack or an open side. A watertight mesh has none; an open floor, an open
  wheel arch or a crack makes them what generalized winding numbers recovered.

:func:`asset_fill` gives the same for one asset in its own frame at a reference voxel size: what
the ADMesh library records per asset (``fill_method``, ``fill_voxel_size``, ``fill_voxels``,
``hole_fill_voxels``, ``hole_fill_fraction``). It runs at ingest, so it does only the work its
method needs: a surface asset one voxelization, a parity asset (every filled part watertight)
no flood fill -- none of its filled voxels can come from a hole, since the surface voxels (every
voxel whose closed box meets a triangle) seal each closed part -- and only a winding asset all of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import AssetGeometry, SceneMesh
from carlaocc.schemas.voxels import SparseVoxels
from carlaocc.stages.voxelize.compose import voxelize_scene
from carlaocc.stages.voxelize.sparse import occupied_voxels
from carlaocc.stages.voxelize.fill import FillMethod, fill_method, fills

__all__ = ["FillBreakdown", "fill_breakdown", "sparse_fill_breakdown", "outside", "AssetFill", "asset_fill", "asset_meshes", "reference_grid",
           "reference_voxel_size", "FILL_REFERENCE_VOXEL", "FILL_REFERENCE_MAX_EDGE"]

FILL_REFERENCE_VOXEL: float = 0.1
"""Voxel edge (m) at which an asset's fill is measured (ingest time: about a quarter of ingest) ..."""
FILL_REFERENCE_MAX_EDGE: int = 64
"""... unless the asset's longest side would span more voxels than this: then side / this."""


@dataclass(frozen=True)
class FillBreakdown:
    """Voxel counts of one voxelization (see the module docstring)."""

    surface: int
    filled: int
    from_holes: int

    @property
    def total(self) -> int:
        return self.surface + self.filled


def fill_breakdown(meshes: Sequence[SceneMesh], grid: GridSpec, fill: str = "auto",
                   solid: np.ndarray | None = None, surface: np.ndarray | None = None) -> FillBreakdown:
    """Surface, filled and hole-handled voxel counts of ``meshes`` (grid frame, metres) on ``grid``
    under ``fill``. ``solid`` and ``surface`` may pass the semantic volumes of the voxelizations
    under ``fill`` and ``"surface"`` when the caller already has them (computed otherwise)."""
    if surface is None and solid is not None and not any(fills(m.semantic_id, m.part, fill) for m in meshes):
        surface = solid  # no mesh is filled: the surface-only voxelization is the same grid
    if surface is None:
        surface, _ = voxelize_scene(meshes, grid, fill="surface")
    if solid is None:
        solid, _ = voxelize_scene(meshes, grid, fill=fill)
    surf = surface > 0
    added = (solid > 0) & ~surf
    if not added.any():  # nothing filled: no flood fill (a labelling of the whole grid) needed
        return FillBreakdown(int(surf.sum()), 0, 0)
    # filled voxels a flood fill from the boundary reaches were reached through an opening
    from_holes = added & outside(surf)
    return FillBreakdown(int(surf.sum()), int(added.sum()), int(from_holes.sum()))


def sparse_fill_breakdown(meshes: Sequence[SceneMesh], voxels: SparseVoxels, fill: str = "auto") -> FillBreakdown:
    """:func:`fill_breakdown` of ``meshes`` given their voxelization under ``fill`` as occupied
    voxels: the same counts, with memory proportional to the occupied voxels when no mesh is
    filled or the fill adds nothing (a dense boolean grid only for the flood fill otherwise)."""
    if not any(fills(m.semantic_id, m.part, fill) for m in meshes):
        return FillBreakdown(len(voxels), 0, 0)  # no mesh filled: every voxel is a surface voxel
    # 1. the surface-only voxelization, sparse too; the filled voxels are the others
    surface = occupied_voxels(meshes, voxels.grid, fill="surface")
    added = np.setdiff1d(voxels.index, surface.index, assume_unique=True)
    if len(added) == 0:
        return FillBreakdown(len(surface), 0, 0)
    # 2. the flood fill from the boundary needs the whole grid: a boolean one
    surf = np.zeros(tuple(int(s) for s in voxels.grid.shape), dtype=bool)
    surf.reshape(-1)[surface.index] = True
    from_holes = int(outside(surf).reshape(-1)[added].sum())
    return FillBreakdown(len(surface), len(added), from_holes)


def outside(surface: np.ndarray) -> np.ndarray:
    """Free voxels (not ``surface``) a flood fill from the grid's boundary reaches through free
    voxels (6-connectivity): ``~scipy.ndimage.binary_fill_holes(surface)``, by one labelling
    pass instead of iterated dilations (several times faster on an asset's grid)."""
    from scipy import ndimage

    # 1. the 6-connected components of the free voxels
    labels, n = ndimage.label(~surface)
    # 2. the components that touch one of the grid's six faces
    faces = (labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1])
    touching = np.zeros(n + 1, dtype=bool)
    touching[np.concatenate([f.ravel() for f in faces])] = True
    touching[0] = False  # label 0: surface voxels
    # 3. their voxels
    return touching[labels]


@dataclass(frozen=True)
class AssetFill:
    """How one asset is filled under ``auto`` and how much of its volume came from hole handling."""

    method: FillMethod  # surface (no part filled), parity (filled parts watertight), winding (some open)
    voxel_size: float  # metres, the reference voxel edge used
    voxels: int  # occupied voxels of the asset at that size (surface + filled)
    filled: int  # voxels the fill added
    from_holes: int  # of those, voxels reached only through holes

    @property
    def hole_fraction(self) -> float:
        """Share of the asset's voxels that came from hole handling."""
        return self.from_holes / self.voxels if self.voxels else 0.0

    def record_fields(self) -> dict[str, object]:
        """These figures under their ``AssetRecord`` field names."""
        return {"fill_method": self.method, "fill_voxel_size": float(self.voxel_size),
                "fill_voxels": int(self.voxels), "hole_fill_voxels": int(self.from_holes),
                "hole_fill_fraction": float(self.hole_fraction)}


def reference_voxel_size(extent: np.ndarray) -> float:
    """:data:`FILL_REFERENCE_VOXEL`, or coarser so the longest side spans at most
    :data:`FILL_REFERENCE_MAX_EDGE` voxels."""
    longest = float(np.max(extent)) if len(extent) else 0.0
    return max(FILL_REFERENCE_VOXEL, longest / FILL_REFERENCE_MAX_EDGE)


def asset_meshes(geom: AssetGeometry) -> tuple[list[SceneMesh], FillMethod]:
    """The asset's parts with faces as scene meshes in its own frame (metres; thing parts one
    instance, stuff parts instance 0) and how ``auto`` fills the asset: ``winding`` when a filled
    part is open, else ``parity`` when a part is filled, else ``surface``."""
    meshes = []
    methods = set()
    for part, closed in zip(geom.parts, geom.part_closed, strict=True):
        if len(part.faces) == 0:
            continue
        cls = taxonomy.by_id(int(part.semantic_id))
        thing = cls.kind == "thing"
        meshes.append(SceneMesh(part.vertices, part.faces, cls.id, 1 if thing else 0, not thing, bool(closed),
                                name=part.name, part=part.name))
        methods.add(fill_method(fills(cls.id, part.name), bool(closed)))
    method: FillMethod = "winding" if "winding" in methods else "parity" if "parity" in methods else "surface"
    return meshes, method


def reference_grid(meshes: Sequence[SceneMesh]) -> GridSpec | None:
    """The grid an asset's fill is measured on: :func:`reference_voxel_size` voxels on the lattice
    of that size (multiples of it from the asset's origin) around the meshes' finite vertices,
    plus a margin of one voxel (the flood fill starts from free boundary voxels); None without
    a finite vertex."""
    V = np.concatenate([m.vertices for m in meshes]) if meshes else np.zeros((0, 3))
    V = V[np.isfinite(V).all(axis=1)]
    if len(V) == 0:
        return None
    lo, hi = V.min(axis=0), V.max(axis=0)
    voxel_size = reference_voxel_size(hi - lo)
    g_lo = np.floor(lo / voxel_size) * voxel_size - voxel_size
    g_hi = np.ceil(hi / voxel_size) * voxel_size + voxel_size
    return GridSpec(region_min=tuple(float(c) for c in g_lo), region_max=tuple(float(c) for c in g_hi),
                    voxel_size=voxel_size)


def asset_fill(geom: AssetGeometry) -> AssetFill:
    """The fill of an asset in its own frame (metres), every part under ``auto``, on its
    :func:`reference_grid`: the method (:func:`asset_meshes`), the occupied voxels, the voxels
    the fill added and, of those, the ones reached only through holes (see the module doc)."""
    meshes, method = asset_meshes(geom)
    grid = reference_grid(meshes)
    if grid is None:
        return AssetFill(method, FILL_REFERENCE_VOXEL, 0, 0, 0)
    voxel_size = grid.voxel_size
    # 1. the surface voxels; with no part filled, ``auto`` writes nothing else (one tile: a
    # filled mesh's column crossings are then computed once, not once per 64-voxel slab)
    whole = int(grid.shape[0])
    surface, _ = voxelize_scene(meshes, grid, fill="surface", tile_x=whole)
    surf = surface > 0
    n_surface = int(np.count_nonzero(surf))
    if method == "surface":
        return AssetFill(method, voxel_size, n_surface, 0, 0)
    # 2. the solid under ``auto``: every surface voxel is written there too, so the fill added the rest
    solid, _ = voxelize_scene(meshes, grid, fill="auto", tile_x=whole)
    voxels = int(np.count_nonzero(solid))
    if method == "parity":
        # every filled part watertight: a free 6-connected path from a voxel centre inside a
        # closed part to the boundary crosses its surface inside one of the path's voxels, which
        # the (conservative) surface voxelization marks -- so no filled voxel came from a hole,
        # and the flood fill is skipped
        return AssetFill(method, voxel_size, voxels, voxels - n_surface, 0)
    # 3. some filled part open: the filled voxels a flood fill from the boundary reaches
    b = fill_breakdown(meshes, grid, "auto", solid=solid, surface=surface)
    return AssetFill(method, voxel_size, b.total, b.filled, b.from_holes)
