"""``carlaocc voxelize``: the voxelizer on any mesh files or ADMesh assets, outside a dataset.

Each input is a mesh file (anything trimesh reads: OBJ, PLY, STL, OFF, GLB/glTF; a multi-mesh
file is concatenated) labelled by ``--class``, or the id of an ADMesh asset in ``--root``, whose
parts keep their own classes. Thing inputs get instance ids 1, 2, ... in argument order; stuff
gets 0. Inputs are filled according to ``--fill`` (one rule with the pipeline,
:mod:`carlaocc.stages.voxelize.fill`: ``auto`` fills volumetric classes -- watertight meshes by
column parity, open ones by generalized winding numbers -- ``solid`` every input, ``surface``
none); a file's name is its part name (``trunk`` marks a tree trunk). The grid is the inputs'
bounding box snapped to the voxel lattice of the origin (0, 0, 0), unless ``--origin`` and
``--shape`` give it. Meshes are used as they are (metres, their own frame). A file whose faces
all have zero area (the ingest stage's degenerate-face rule: twice the area below 1e-12 of the
squared bounding-box diagonal, or a repeated vertex) is an input error naming it: it would write
an empty or line-thin grid without a word.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.voxels import SparseVoxels
from carlaocc.stages.geometry import DEGENERATE_REL, is_watertight
from carlaocc.stages.voxelize.fill import fill_method, fills

# Imports: what only some runs need (trimesh for mesh files, the dataset store for asset ids,
# scipy's flood fill for filled meshes' hole counts, Zarr for .zarr) is imported where used, so
# a run imports only what it uses (``python -X importtime``: trimesh alone is ~0.8 s).

MAX_VOXELS = 2**31  # a grid beyond this is almost always a unit mistake (millimetres as metres)


class InputError(ValueError):
    """A bad standalone input; the message names it."""


@dataclass(frozen=True)
class VoxelizeResult:
    voxels: SparseVoxels  # the occupied voxels and their labels (grid: voxels.grid)
    meshes: list[SceneMesh]
    seconds: float = 0.0  # the voxelization's wall time

    @property
    def grid(self) -> GridSpec:
        return self.voxels.grid


def fill_summary(result: VoxelizeResult, fill: str) -> str:
    """One line on where the voxels came from: surface, fill (and how: parity or winding
    numbers, per mesh), and hole handling (filled voxels a flood fill would not have found)."""
    from carlaocc.stages.voxelize.breakdown import sparse_fill_breakdown

    b = sparse_fill_breakdown(result.meshes, result.voxels, fill)
    methods = [fill_method(fills(m.semantic_id, m.part, fill), m.closed) for m in result.meshes]
    how = ", ".join(f"{methods.count(k)} by {k}" for k in ("parity", "winding") if methods.count(k))
    return (f"voxels: {b.surface:,} surface, {b.filled:,} filled ({how or 'no mesh filled'}), "
            f"{b.from_holes:,} of them from hole handling")


def _load_file(path: Path, weld: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The file's vertices and triangles; ``weld``: coincident vertices merged (STL and many
    exporters repeat them per face), which only matters where closedness does (a filled mesh:
    parity or winding numbers) -- the voxels of a surface are the same either way."""
    from carlaocc.catalog.mesh_files import MeshFileError, read_mesh

    try:
        V, F = read_mesh(path)
    except MeshFileError as exc:
        raise InputError(str(exc)) from None
    if len(F) == 0:
        raise InputError(f"{path}: the file holds no triangles")
    if not np.isfinite(V).all():
        raise InputError(f"{path}: {int((~np.isfinite(V)).any(axis=1).sum())} vertices are NaN or infinite")
    if weld:
        uniq, inverse = np.unique(V, axis=0, return_inverse=True)
        V, F = uniq, inverse.reshape(-1)[F]
    if not _has_area(V, F):
        raise InputError(f"{path}: all {len(F)} faces have zero area (no triangle with an area): nothing "
                         "to voxelize; check or re-export the mesh")
    return V, F


def _has_area(V: np.ndarray, F: np.ndarray) -> bool:
    """Whether any face is non-degenerate, by the ingest stage's rule (``DEGENERATE_REL``)."""

    # 1. the bounding box of the vertices the faces use (a mask: no sort)
    mask = np.zeros(len(V), dtype=bool)
    mask[F.reshape(-1)] = True
    used = V[mask]
    diag2 = float(np.sum((used.max(axis=0) - used.min(axis=0)) ** 2))
    # 2. faces in blocks until one has an area (usually the first block: no pass over them all)
    for s in range(0, len(F), 65536):
        f = F[s:s + 65536]
        cross = np.cross(V[f[:, 1]] - V[f[:, 0]], V[f[:, 2]] - V[f[:, 0]])
        twice_area2 = np.einsum("ij,ij->i", cross, cross)
        repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
        if np.any(~repeated & (twice_area2 > (DEGENERATE_REL * diag2) ** 2)):
            return True
    return False


def _classes(classes: list[str], n: int) -> list[taxonomy.SemanticClass]:
    if n == 0:
        if classes:
            raise InputError("--class labels mesh files, but every input is an ADMesh asset id (their parts keep "
                             "their own classes)")
        return []
    if not classes:
        raise InputError("give --class for the mesh files (one for all, or one per file)")
    if len(classes) not in (1, n):
        raise InputError(f"--class given {len(classes)} times for {n} mesh files: give it once or once per file")
    try:
        found = [taxonomy.by_name(c) for c in classes]
    except KeyError as exc:
        raise InputError(str(exc.args[0])) from None
    return found * n if len(found) == 1 else found


def load_inputs(items: list[str], classes: list[str], store=None, fill: str = "auto") -> list[SceneMesh]:
    """The SceneMeshes of the inputs: files labelled by ``classes``, asset ids from ``store`` (a
    :class:`carlaocc.catalog.store.Store`). A file's mesh is welded and its closedness found only
    when ``fill`` fills it (closedness picks parity or winding numbers); otherwise it is used as
    read, with ``closed`` False."""
    files = [Path(i) for i in items if os.path.exists(i)]
    missing = [i for i in items if not os.path.exists(i)]
    if missing and store is None:
        raise InputError(f"{missing[0]}: no such file (and no --root to look it up as an ADMesh asset id)")
    labels = iter(_classes(classes, len(files)))
    assets = {}
    if missing:
        from carlaocc.catalog.store import StoreError
        from carlaocc.pipeline.tasks.frame import load_geometry

        try:
            assets = load_geometry(store, set(missing), [])
        except StoreError as exc:
            raise InputError(f"{missing[0]}: no such file, and not an ADMesh asset of {store.url} ({exc})") from None
    out: list[SceneMesh] = []
    next_instance = 1
    for item in items:
        if os.path.exists(item):
            cls = next(labels)
            filled = fills(cls.id, Path(item).stem, fill)
            V, F = _load_file(Path(item), weld=filled)
            thing = cls.kind == "thing"
            out.append(SceneMesh(V, F, cls.id, next_instance if thing else 0, not thing,
                                 filled and is_watertight(F), name=str(item), part=Path(item).stem))
            next_instance += thing
        else:
            geom = assets[item]
            thing = False
            for part, closed in zip(geom.parts, geom.part_closed):
                cls = taxonomy.by_id(part.semantic_id)
                is_thing = cls.kind == "thing"
                out.append(SceneMesh(part.vertices, part.faces, cls.id, next_instance if is_thing else 0,
                                     not is_thing, closed, name=f"{item}/{part.name}", transparent=part.transparent,
                                     part=part.name))
                thing |= is_thing
            next_instance += thing
    return out


def grid_for(meshes: list[SceneMesh], voxel_size: float, origin=None, shape=None) -> GridSpec:
    """The grid: ``origin`` + ``shape`` when given, else the meshes' bounding box snapped out to
    multiples of ``voxel_size`` (so voxels align with those of any other run at that size)."""
    if not (voxel_size > 0 and math.isfinite(voxel_size)):
        raise InputError(f"--voxel-size must be a positive number of metres, got {voxel_size}")
    if (origin is None) != (shape is None):
        raise InputError("give --origin and --shape together (or neither: the meshes' bounding box)")
    if origin is None:
        pts = np.concatenate([m.vertices for m in meshes]) if meshes else np.zeros((0, 3))
        if len(pts) == 0:
            raise InputError("no vertices to voxelize")
        lo = np.floor(pts.min(axis=0) / voxel_size) * voxel_size
        n = np.maximum(np.ceil((pts.max(axis=0) - lo) / voxel_size - 1e-9).astype(np.int64), 1)
        origin, shape = tuple(float(c) for c in lo), tuple(int(c) for c in n)
    if len(origin) != 3 or len(shape) != 3 or min(shape) < 1:
        raise InputError(f"--origin needs x,y,z and --shape nx,ny,nz (positive), got {origin} and {shape}")
    if not all(math.isfinite(c) for c in origin):
        raise InputError(f"--origin {','.join(f'{c:g}' for c in origin)}: every coordinate must be a finite "
                         f"number of metres")
    total = math.prod(int(s) for s in shape)
    if total > MAX_VOXELS:
        raise InputError(f"the grid would have {total:,} voxels ({shape[0]}x{shape[1]}x{shape[2]} at {voxel_size} m): "
                         f"are the meshes in millimetres? give a larger --voxel-size or --origin/--shape")
    hi = tuple(o + n * voxel_size for o, n in zip(origin, shape))

    from pydantic import ValidationError

    try:
        return GridSpec(region_min=tuple(origin), region_max=hi, voxel_size=voxel_size)
    except ValidationError as exc:  # one line naming the option the user typed
        err = exc.errors()[0]
        option = {"region_min": "--origin", "region_max": "--origin/--shape", "voxel_size": "--voxel-size"}.get(
            str(err["loc"][0]) if err["loc"] else "", "--origin/--shape")
        raise InputError(f"{option}: {str(err['msg']).removeprefix('Value error, ')}") from None


def voxelize_inputs(meshes: list[SceneMesh], grid: GridSpec, fill: str = "auto") -> VoxelizeResult:
    """The occupied voxels of ``meshes`` on ``grid``, built tile by tile (memory: the occupied
    voxels and one tile, not the dense grid)."""
    from carlaocc.stages.voxelize.sparse import occupied_voxels

    t0 = time.perf_counter()
    voxels = occupied_voxels(meshes, grid, fill=fill)
    return VoxelizeResult(voxels, meshes, time.perf_counter() - t0)


def save_result(result: VoxelizeResult, out: Path, dense: bool = False) -> None:
    """Write the voxels to ``out`` (:mod:`carlaocc.catalog.voxel_file`: a sparse ``.npz``, the
    dense ``.npz`` layout with ``dense``, or ``.zarr``)."""
    from carlaocc.catalog.voxel_file import VoxelFileError, save_voxels

    try:
        save_voxels(result.voxels, out, dense=dense)
    except VoxelFileError as exc:
        raise InputError(str(exc)) from None
