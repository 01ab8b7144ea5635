"""What every per-frame task reads: a sequence's frames, a frame's panoptic scene, the asset
geometry behind it (cached per worker by content), and the sequences partitioning iterates.

Shared by the voxelize and sensors wiring (``frame_inputs``), the scene tools and the benchmarks;
like every wiring module, it reads through the catalog and calls the pure compute of
``carlaocc.stages``.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import OrderedDict

import numpy as np
import pyarrow.compute as pc

from carlaocc.catalog.meshes import load_glb_arrays
from carlaocc.catalog.parquet import ParquetTable, from_table
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.textures import textures_from_npz
from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, FrameRecord, PartRecord, PlacementRecord,
                                      SequenceRecord)
from carlaocc.schemas.taxonomy import thing_ids
from carlaocc.stages.geometry import geometry_hash, is_watertight
from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame, frame_region
from carlaocc.stages.scenes.people.pedestrians import rig_pedestrian

# per-worker caches: asset geometry by file content, pedestrian rigs, each town's placement index
_GEOMETRY_CACHE: OrderedDict[tuple, AssetGeometry] = OrderedDict()
_RIG_CACHE: OrderedDict[tuple[str, str], object] = OrderedDict()
_INDEX_CACHE: OrderedDict[tuple[str, str, str | None], object] = OrderedDict()
_TABLE_CACHE: OrderedDict[tuple, list] = OrderedDict()


def _cached(cache: OrderedDict, key, make, size: int):
    """``cache[key]``, made by ``make()`` on a miss; least recently used entries beyond ``size``
    are dropped."""
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    value = cache[key] = make()
    if len(cache) > size:
        cache.popitem(last=False)
    return value


def _mesh_geometry(store: Store, rel: str, key: tuple, build) -> AssetGeometry:
    """``build(arrays)`` of the GLB ``rel``, cached per worker by the file's content and ``key``
    (what else the geometry is made of): the same object comes back while nothing changed, so
    callers may cache work on it by identity."""
    data = store.read_bytes(rel)
    return _cached(_GEOMETRY_CACHE, (rel, hashlib.sha256(data).hexdigest(), key),
                   lambda: build(load_glb_arrays(data)), 1024)


def library_rows(store: Store, model: type[AssetRecord] | type[PartRecord]) -> list:
    """The rows of a mesh-library table (``AssetRecord`` or ``PartRecord``), validated once per
    worker and content of its files: every frame's task reads the whole library's tables (some
    2,000 rows at 0.05-0.1 CPU s of validation a frame); the same list comes back while no file
    of the table changed (its rows are frozen records)."""
    table = ParquetTable(store, model)
    paths = table.paths()
    digest = hashlib.sha256()
    for rel in paths:
        digest.update(rel.encode() + b"\0" + hashlib.sha256(store.read_bytes(rel)).digest())
    return _cached(_TABLE_CACHE, (store.url, model.__name__, digest.hexdigest()), table.load, 8)


def load_geometry(store: Store, asset_ids: set[str], placements: list[PlacementRecord]) -> dict[str, AssetGeometry]:
    """AssetGeometry of every id in ``asset_ids``: ADMesh assets (the parts table gives each part's
    class and closedness) or, for ids not in the library, the town stuff mesh of the placement that
    references it (one class per stuff placement; closedness measured)."""
    assets = {a.asset_id: a for a in library_rows(store, AssetRecord)}
    # parts by asset, once each: two source items with the same standardized geometry (two
    # identical files) are one asset whose parts both items' tables hold
    parts: dict[str, dict[int, PartRecord]] = {}
    for p in library_rows(store, PartRecord):
        parts.setdefault(p.asset_id, {}).setdefault(p.part_index, p)
    stuff = {pl.asset_id: pl for pl in placements if pl.asset_id not in assets}
    out: dict[str, AssetGeometry] = {}
    for aid in sorted(asset_ids):
        if aid in assets:
            recs = tuple(sorted(parts.get(aid, {}).values(), key=lambda r: r.part_index))

            tex_rel = assets[aid].texture_path
            tex_bytes = store.read_bytes(tex_rel) if tex_rel else b""

            def asset_geometry(arrays, aid=aid, recs=recs, tex_rel=tex_rel, tex_bytes=tex_bytes) -> AssetGeometry:
                if len(arrays) != len(recs):
                    raise StoreError(f"asset {aid}: mesh has {len(arrays)} parts, parts table {len(recs)}")
                textures = textures_from_npz(tex_bytes, f"{store.url}/{tex_rel}") if tex_rel else {}
                parts = []
                for k, (r, (v, f)) in enumerate(zip(recs, arrays)):
                    uv, image = textures.get(k, (None, None))
                    if uv is not None and len(uv) != len(f):
                        raise StoreError(f"asset {aid}: part {k} has {len(f)} faces, its texture "
                                         f"coordinates {len(uv)} ({tex_rel})")
                    parts.append(MeshPart(r.name, v, f, r.semantic_id, r.material, r.transparent, tuple(r.color),
                                          corner_uv=uv, image=image))
                return AssetGeometry(asset_id=aid, parts=tuple(parts), part_closed=tuple(r.watertight for r in recs))

            # the cache key: the parts' rows, hashable (their colour is a list), and the textures' content
            key = (aid, tex_rel, hashlib.sha256(tex_bytes).hexdigest(), tuple(r.model_dump_json() for r in recs))
            out[aid] = _mesh_geometry(store, assets[aid].mesh_path, key, asset_geometry)
        elif aid in stuff:
            pl = stuff[aid]

            def stuff_geometry(arrays, aid=aid, pl=pl) -> AssetGeometry:
                return AssetGeometry(
                    asset_id=aid,
                    parts=tuple(MeshPart(f"{pl.name}_{i}", v, f, pl.semantic_id) for i, (v, f) in enumerate(arrays)),
                    part_closed=tuple(is_watertight(f) for _, f in arrays),
                )

            out[aid] = _mesh_geometry(store, pl.mesh_path, (aid, pl.name, pl.semantic_id), stuff_geometry)
        else:
            raise StoreError(f"asset {aid} is referenced by the scene but is neither in admesh/assets "
                             f"nor a town mesh")
    return out


def pedestrian_rigs(geometry: dict[str, AssetGeometry]):
    """``asset_id -> PedestrianRig`` of the pedestrian assets in ``geometry``, cached per worker by
    asset id and geometry content (each asset's content hashed once per call of this)."""

    keys: dict[str, tuple[str, str]] = {}  # asset id -> cache key

    def rig(asset_id: str):
        geom = geometry[asset_id]
        if asset_id not in keys:
            keys[asset_id] = (asset_id, geometry_hash([(p.vertices, p.faces) for p in geom.parts]))
        return _cached(_RIG_CACHE, keys[asset_id], lambda: rig_pedestrian(geom), 256)

    return rig


def pedestrian_geometry(geometry: dict[str, AssetGeometry]):
    """``(asset_id, phase_index) -> AssetGeometry``: pedestrians posed in a canonical gait phase
    (rigs from :func:`pedestrian_rigs`)."""
    rig = pedestrian_rigs(geometry)
    return lambda asset_id, phase_index: rig(asset_id).posed(phase_index)


def frame_rows(store: Store, model, seq_id: str, frame_index: int) -> list:
    """The rows of one frame of a per-sequence table (filtered in Arrow before validation)."""

    table = ParquetTable(store, model).load_arrow([seq_id])
    return from_table(model, table.filter(pc.equal(table["frame_index"], frame_index)))


@dataclasses.dataclass(frozen=True)
class FrameInputs:
    """What one frame's tasks read: its sequence, frame and actor rows and the panoptic scene."""

    sequence: SequenceRecord
    frame: FrameRecord
    actors: list[ActorStateRecord]
    scene: list  # SceneMesh, LiDAR frame, cut to the requested region

    @property
    def up(self) -> np.ndarray:
        """The world's up direction (0, 0, 1) in the frame's LiDAR frame: the last row of the
        LiDAR-to-world rotation (the LiDAR's z when the ego stands level)."""
        return np.asarray(self.frame.lidar_pose, dtype=np.float64).reshape(4, 4)[2, :3].copy()


def frame_inputs(store: Store, seq_id: str, frame_index: int, region, taxonomy: str | None = None) -> FrameInputs:
    """The rows and panoptic scene (LiDAR frame, cut to ``region`` = (lo, hi)) of one frame;
    ``taxonomy`` names the label table whose stuff parts carry instance 0 (None: the default)."""

    t_seq = ParquetTable(store, SequenceRecord)
    sequences = t_seq.load([seq_id]) if t_seq.exists(seq_id) else []
    if not sequences:
        raise StoreError(f"sequence {seq_id!r} is not in {store.url}: run the scenes stage first")
    (sequence,) = sequences
    frames = frame_rows(store, FrameRecord, seq_id, frame_index)
    if not frames:
        raise StoreError(f"sequence {seq_id} has no frame {frame_index} (it has {sequence.frame_count})")
    actors = frame_rows(store, ActorStateRecord, seq_id, frame_index)
    # the town's placement index, kept per worker while the placements file is unchanged (its
    # per-asset preparation of big stuff meshes is then reused across frames)
    t_place = ParquetTable(store, PlacementRecord)
    key = sequence.placements_key()
    index = _cached(_INDEX_CACHE, (store.url, key, store.fingerprint(t_place.path(key))),
                    lambda: PlacementIndex(t_place.load([key])), 8)
    # geometry of the placements whose world AABB meets the frame's region, and of the actors
    selected = index.select(*frame_region(frames[0], *region))
    needed = {index.placements[i].asset_id for i in selected} | {a.asset_id for a in actors}
    geometry = load_geometry(store, needed, index.placements)
    scene = assemble_frame(frames[0], actors, index, geometry, region,
                           pedestrian_geometry=pedestrian_geometry(geometry), ego_asset_id=sequence.ego_asset_id,
                           things=frozenset(thing_ids(taxonomy)))
    return FrameInputs(sequence, frames[0], actors, scene)


def frame_scene(store: Store, seq_id: str, frame_index: int, region, taxonomy: str | None = None) -> list:
    """The panoptic scene (list of SceneMesh, LiDAR frame) of one frame, cut to ``region`` =
    (lo, hi) in the LiDAR frame, under label table ``taxonomy``."""
    return frame_inputs(store, seq_id, frame_index, region, taxonomy).scene
