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
import trimesh
import zarr
from pydantic import ValidationError

from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.tasks.frame import load_geometry
from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.stages.geometry import is_watertight
from carlaocc.stages.ingest.repair import DEGENERATE_REL
from carlaocc.stages.voxelize import voxelize_scene
from carlaocc.stages.voxelize.breakdown import fill_breakdown
from carlaocc.stages.voxelize.fill import fill_method, fills

MAX_VOXELS = 2**31  # a grid beyond this is almost always a unit mistake (millimetres as metres)


class InputError(ValueError):
    """A bad standalone input; the message names it."""


@dataclass(frozen=True)
class VoxelizeResult:
    grid: GridSpec
    semantic: np.ndarray  # uint8 (X, Y, Z)
    instance: np.ndarray  # uint32 (X, Y, Z)
    meshes: list[SceneMesh]
    seconds: float = 0.0  # the voxelization's wall time


def fill_summary(result: VoxelizeResult, fill: str) -> str:
    """One line on where the voxels came from: surface, fill (and how: parity or winding
    numbers, per mesh), and hole handling (filled voxels a flood fill would not have found)."""

    b = fill_breakdown(result.meshes, result.grid, fill, solid=result.semantic)
    methods = [fill_method(fills(m.semantic_id, m.part, fill), m.closed) for m in result.meshes]
    how = ", ".join(f"{methods.count(k)} by {k}" for k in ("parity", "winding") if methods.count(k))
    return (f"voxels: {b.surface:,} surface, {b.filled:,} filled ({how or 'no mesh filled'}), "
            f"{b.from_holes:,} of them from hole handling")


def _load_file(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for a corrupt file
        raise InputError(f"{path}: cannot read the mesh ({type(exc).__name__}: {exc})") from exc
    V = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    F = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(F) == 0:
        raise InputError(f"{path}: the file holds no triangles")
    if not np.isfinite(V).all():
        raise InputError(f"{path}: {int((~np.isfinite(V)).any(axis=1).sum())} vertices are NaN or infinite")
    # weld coincident vertices (STL and many exporters repeat them per face) so closedness is seen
    uniq, inverse = np.unique(V, axis=0, return_inverse=True)
    F = inverse.reshape(-1)[F]
    if not _has_area(uniq, F):
        raise InputError(f"{path}: all {len(F)} faces have zero area (no triangle with an area): nothing "
                         "to voxelize; check or re-export the mesh")
    return uniq, F


def _has_area(V: np.ndarray, F: np.ndarray) -> bool:
    """Whether any face is non-degenerate, by the ingest stage's rule (``DEGENERATE_REL``)."""

    used = V[np.unique(F)]
    diag2 = float(np.sum((used.max(axis=0) - used.min(axis=0)) ** 2))
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    twice_area2 = np.einsum("ij,ij->i", cross, cross)
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    return bool(np.any(~repeated & (twice_area2 > (DEGENERATE_REL * diag2) ** 2)))


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


def load_inputs(items: list[str], classes: list[str], store: Store | None) -> list[SceneMesh]:
    """The SceneMeshes of the inputs: files labelled by ``classes``, asset ids from ``store``."""
    files = [Path(i) for i in items if os.path.exists(i)]
    missing = [i for i in items if not os.path.exists(i)]
    if missing and store is None:
        raise InputError(f"{missing[0]}: no such file (and no --root to look it up as an ADMesh asset id)")
    labels = iter(_classes(classes, len(files)))
    assets = {}
    if missing:
        try:
            assets = load_geometry(store, set(missing), [])
        except StoreError as exc:
            raise InputError(f"{missing[0]}: no such file, and not an ADMesh asset of {store.url} ({exc})") from None
    out: list[SceneMesh] = []
    next_instance = 1
    for item in items:
        if os.path.exists(item):
            V, F = _load_file(Path(item))
            cls = next(labels)
            thing = cls.kind == "thing"
            out.append(SceneMesh(V, F, cls.id, next_instance if thing else 0, not thing, is_watertight(F),
                                 name=str(item), part=Path(item).stem))
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

    try:
        return GridSpec(region_min=tuple(origin), region_max=hi, voxel_size=voxel_size)
    except ValidationError as exc:  # one line naming the option the user typed
        err = exc.errors()[0]
        option = {"region_min": "--origin", "region_max": "--origin/--shape", "voxel_size": "--voxel-size"}.get(
            str(err["loc"][0]) if err["loc"] else "", "--origin/--shape")
        raise InputError(f"{option}: {str(err['msg']).removeprefix('Value error, ')}") from None


def voxelize_inputs(meshes: list[SceneMesh], grid: GridSpec, fill: str = "auto") -> VoxelizeResult:
    t0 = time.perf_counter()
    semantic, instance = voxelize_scene(meshes, grid, fill=fill)
    return VoxelizeResult(grid, semantic, instance, meshes, time.perf_counter() - t0)


def save_result(result: VoxelizeResult, out: Path) -> None:
    """``.npz`` (compressed: semantic, instance, voxel_size, voxel_origin, shape) or ``.zarr``
    (a Zarr v3 group with ``semantic`` and ``instance`` arrays carrying the grid attributes)."""
    suffix = out.suffix.lower()
    out.parent.mkdir(parents=True, exist_ok=True)
    g = result.grid
    if suffix == ".npz":
        tmp = out.with_name(out.name + ".tmp.npz")
        np.savez_compressed(tmp, semantic=result.semantic, instance=result.instance,
                            voxel_size=np.float64(g.voxel_size), voxel_origin=np.asarray(g.origin, np.float64),
                            shape=np.asarray(g.shape, np.int64))
        tmp.replace(out)
    elif suffix == ".zarr":
        root = zarr.open_group(str(out), mode="w")
        X, Y, Z = g.shape
        chunks = (min(128, X), min(128, Y), Z)
        attrs = {**g.attrs(), "dims": ["x", "y", "z"], "taxonomy_version": taxonomy.TAXONOMY_VERSION}
        for name, data in (("semantic", result.semantic), ("instance", result.instance)):
            arr = root.create_array(name, shape=data.shape, chunks=chunks, dtype=data.dtype, fill_value=0,
                                    attributes=attrs)
            arr[...] = data
    else:
        raise InputError(f"--out must end in .npz or .zarr, got {out}")
