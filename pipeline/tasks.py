"""Task bodies: for one partition, read inputs through the catalog, call the pure compute of
``stages``, write outputs through the catalog, and return the outputs' fingerprints.

These are the only functions that know both where data lives and what computes it. They run
inside Dask workers, so they take a store (a URL) and a frozen config, never open objects.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import OrderedDict

import numpy as np

from carlaocc.catalog.admesh import dedupe_assets
from carlaocc.catalog.meshes import MeshStore, load_glb_arrays
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.registry import Partition
from carlaocc.schemas.configs import (IngestConfig, MetricsConfig, ScenesConfig, SensorsConfig, SourceIngestConfig, TownSpec,
                             VoxelizeConfig)
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import (
    ActorStateRecord,
    AssetRecord,
    ClassQualityRecord,
    FrameRecord,
    PartRecord,
    PlacementRecord,
    QualityRecord,
    QuarantineRecord,
    SensorPoseRecord,
    SequenceRecord,
    TownRecord,
)
from carlaocc.stages.geometry import AssetGeometry, MeshPart, is_watertight

PROCEDURAL_SOURCE = "procedural"


# -- ingest ---------------------------------------------------------------------------------------
def ingest_task(store: Store, cfg: IngestConfig, part: Partition) -> dict[str, str]:
    """Generate the procedural ADMesh library; write meshes, assets and parts."""
    from carlaocc.stages.ingest import ingest_procedural

    result = ingest_procedural(cfg)
    meshes = MeshStore(store)
    outputs: dict[str, str] = {}
    assets = []
    for rec in result.assets:
        rel = store.asset_mesh_path(rec.asset_id)
        outputs[rel] = meshes.save(rel, result.geometry[rec.asset_id].parts)
        assets.append(rec.model_copy(update={"mesh_path": rel}))
    t_assets = ParquetTable(store, AssetRecord)
    t_parts = ParquetTable(store, PartRecord)
    key = f"source={PROCEDURAL_SOURCE}/{PROCEDURAL_SOURCE}"
    outputs[t_assets.path(key)] = t_assets.save(key, assets)
    outputs[t_parts.path(key)] = t_parts.save(key, result.parts)
    return outputs


# -- ingest of an external source (one item per task) -------------------------------------------
def source_table_key(cfg: SourceIngestConfig, item_key: str) -> str:
    """Table file key of one source item: ``source=<kind>/<root hash>-<item hash>`` (so the
    items of one source root can be listed, and pruned when they disappear)."""
    return f"source={cfg.kind}/{root_digest(cfg.root)}-{hashlib.sha256(item_key.encode()).hexdigest()[:16]}"


def root_digest(root: str) -> str:
    return hashlib.sha256(root.encode()).hexdigest()[:10]


def _raw_asset(src):
    """catalog SourceAsset -> stages RawAsset (same fields; the layers share no types)."""
    from carlaocc.stages.ingest.raw import RawAsset, RawPart

    parts = tuple(RawPart(**{f.name: getattr(p, f.name) for f in dataclasses.fields(RawPart)}) for p in src.parts)
    fields = {f.name: getattr(src, f.name) for f in dataclasses.fields(RawAsset) if f.name != "parts"}
    return RawAsset(parts=parts, **fields)


def ingest_source_task(store: Store, cfg: SourceIngestConfig, part: Partition) -> dict[str, str]:
    """Read one source item, standardize it, and write its mesh and records — or its quarantine
    row. The other outcome's files of the same item are removed, so an item that turned bad (or
    good) is never listed twice."""
    from carlaocc.catalog.sources.base import SourceError, SourceItem
    from carlaocc.catalog.sources.registry import adapter
    from carlaocc.stages.ingest.raw import Rejection
    from carlaocc.stages.ingest.standardize import standardize

    item = SourceItem(key=part.params["item_key"], files=tuple(part.files), meta=part.params.get("meta", {}))
    key = source_table_key(cfg, item.key)
    t_assets, t_parts = ParquetTable(store, AssetRecord), ParquetTable(store, PartRecord)
    t_quarantine = ParquetTable(store, QuarantineRecord)
    source_path = item.files[0] if item.files else item.key
    try:
        src = adapter(cfg.kind, category_map=cfg.category_map).read(cfg.root, item)
        source_path = src.source_path
        result = standardize(_raw_asset(src))
    except SourceError as exc:
        result = Rejection(exc.reason, exc.hint)
    except Exception as exc:  # whatever else one bad file does, the batch goes on
        result = Rejection("unreadable file", f"{type(exc).__name__}: {exc}; check or re-export {source_path}")
    if isinstance(result, Rejection):
        for t in (t_assets, t_parts):
            store.remove(t.path(key))
        row = QuarantineRecord(stage="ingest", source=cfg.kind, source_path=source_path,
                               reason=result.reason, hint=result.hint)
        return {t_quarantine.path(key): t_quarantine.save(key, [row])}
    store.remove(t_quarantine.path(key))
    rel = store.asset_mesh_path(result.asset.asset_id)
    outputs = {rel: MeshStore(store).save(rel, result.geometry.parts)}
    asset = result.asset.model_copy(update={"mesh_path": rel})
    outputs[t_assets.path(key)] = t_assets.save(key, [asset])
    outputs[t_parts.path(key)] = t_parts.save(key, result.parts)
    return outputs


# -- scenes ---------------------------------------------------------------------------------------
def scene_assets(store: Store, cfg: ScenesConfig) -> list[AssetRecord]:
    """The ADMesh assets towns and traffic draw from: the configured sources, duplicates once."""
    assets = dedupe_assets([a for a in ParquetTable(store, AssetRecord).load() if a.source in cfg.asset_sources])
    if not assets:
        raise StoreError(f"no ADMesh assets from sources {', '.join(cfg.asset_sources)} in {store.url}: "
                         f"run the ingest stage first")
    return assets


def read_town_network(spec: TownSpec):
    """The parsed OpenDRIVE network of an opendrive town spec (None for procedural ones)."""
    if spec.style != "opendrive":
        return None
    from carlaocc.catalog.opendrive import read_opendrive
    from carlaocc.catalog.towns import resolve_opendrive

    return read_opendrive(resolve_opendrive(spec.opendrive))


def is_edited(sequence_id: str) -> bool:
    """Edited sequences (``scenes swap``) carry a ``~`` in their id; re-simulating their town
    removes them, since their trajectories are copies of the old simulation."""
    return "~" in sequence_id


def scenes_task(store: Store, cfg: ScenesConfig, part: Partition) -> dict[str, str]:
    """Build one town and simulate its sequences; write stuff meshes, placements, the town row,
    sequences, frames, sensor poses and actors."""
    from carlaocc.stages.scenes import build_town, simulate_town
    from carlaocc.stages.scenes.pedestrians import match_walker_phases

    index = part.params["town_index"]
    spec = cfg.towns[index]
    assets = scene_assets(store, cfg)
    town = build_town(spec, cfg, index, assets, read_town_network(spec), spec.opendrive or "")
    outputs: dict[str, str] = {}
    meshes = MeshStore(store)
    mesh_paths = {a.asset_id: a.mesh_path for a in assets}
    for stuff_id, geom in sorted(town.stuff.items()):
        rel = store.scene_mesh_path(stuff_id)
        outputs[rel] = meshes.save(rel, geom.parts)
        mesh_paths[stuff_id] = rel
    placements = [p.model_copy(update={"mesh_path": mesh_paths[p.asset_id]}) for p in town.placements]
    key = f"town={town.name}"
    t_place, t_town = ParquetTable(store, PlacementRecord), ParquetTable(store, TownRecord)
    outputs[t_place.path(key)] = t_place.save(key, placements)
    net = town.network
    row = TownRecord(
        town=town.name, style=town.style, source=town.source, seed=cfg.seed, road_length=net.road_length,
        lane_count=len(net.lanes), junction_count=len(net.junction_ids),
        walkway_length=float(sum(w.length for w in net.walkways)),
        crosswalk_count=sum(1 for w in net.walkways if w.crosswalk), placement_count=len(placements),
        bounds=[float(v) for v in town.bounds],
    )  # fmt: skip
    outputs[t_town.path(key)] = t_town.save(key, [row])

    tables = {
        "sequence": ParquetTable(store, SequenceRecord),
        "frames": ParquetTable(store, FrameRecord),
        "sensor_poses": ParquetTable(store, SensorPoseRecord),
        "actors": ParquetTable(store, ActorStateRecord),
    }
    written = set()
    for seq in simulate_town(cfg, spec, town, assets, match_phases=match_walker_phases):
        sid = seq.sequence.sequence_id
        written.add(sid)
        rows = {"sequence": [seq.sequence], "frames": seq.frames, "sensor_poses": seq.sensor_poses,
                "actors": seq.actors}
        for name, table in tables.items():
            outputs[table.path(sid)] = table.save(sid, rows[name])
    # sequences this town no longer has (fewer levels or sequences) are removed, not left stale
    for table in tables.values():
        for rel in table.paths():
            sid = rel[len(table.dir) + 1 : -len(".parquet")]
            if not sid.startswith(f"{town.name}_"):
                continue
            # edited sequences (scenes swap) copied trajectories that were just re-simulated or
            # removed: they are stale, so they go too (run swap again)
            if sid not in written or is_edited(sid):
                store.remove(rel)
    return outputs


# -- geometry loading (cached per worker by content) ----------------------------------------------
_GEOMETRY_CACHE: OrderedDict[tuple, AssetGeometry] = OrderedDict()


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


def load_geometry(store: Store, asset_ids: set[str], placements: list[PlacementRecord]) -> dict[str, AssetGeometry]:
    """AssetGeometry of every id in ``asset_ids``: ADMesh assets (the parts table gives each part's
    class and closedness) or, for ids not in the library, the town stuff mesh of the placement that
    references it (one class per stuff placement; closedness measured)."""
    assets = {a.asset_id: a for a in ParquetTable(store, AssetRecord).load()}
    parts: dict[str, list[PartRecord]] = {}
    for p in ParquetTable(store, PartRecord).load():
        parts.setdefault(p.asset_id, []).append(p)
    stuff = {pl.asset_id: pl for pl in placements if pl.asset_id not in assets}
    out: dict[str, AssetGeometry] = {}
    for aid in sorted(asset_ids):
        if aid in assets:
            recs = tuple(sorted(parts.get(aid, []), key=lambda r: r.part_index))

            def asset_geometry(arrays, aid=aid, recs=recs) -> AssetGeometry:
                if len(arrays) != len(recs):
                    raise StoreError(f"asset {aid}: mesh has {len(arrays)} parts, parts table {len(recs)}")
                return AssetGeometry(
                    asset_id=aid,
                    parts=tuple(MeshPart(r.name, v, f, r.semantic_id, r.material, r.transparent)
                                for r, (v, f) in zip(recs, arrays)),
                    part_closed=tuple(r.watertight for r in recs),
                )

            out[aid] = _mesh_geometry(store, assets[aid].mesh_path, (aid, recs), asset_geometry)
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


# -- voxelize -------------------------------------------------------------------------------------
_RIG_CACHE: OrderedDict[tuple[str, str], object] = OrderedDict()
_INDEX_CACHE: OrderedDict[tuple[str, str, str | None], object] = OrderedDict()


def pedestrian_geometry(geometry: dict[str, AssetGeometry]):
    """``(asset_id, phase_index) -> AssetGeometry``: pedestrians posed in a canonical gait phase
    (rigs cached per worker by asset id and geometry content)."""
    from carlaocc.stages.geometry import geometry_hash
    from carlaocc.stages.scenes.pedestrians import rig_pedestrian

    keys: dict[str, tuple[str, str]] = {}  # asset id -> cache key, hashed once per frame

    def posed(asset_id: str, phase_index: int) -> AssetGeometry:
        geom = geometry[asset_id]
        if asset_id not in keys:
            keys[asset_id] = (asset_id, geometry_hash([(p.vertices, p.faces) for p in geom.parts]))
        rig = _cached(_RIG_CACHE, keys[asset_id], lambda: rig_pedestrian(geom), 256)
        return rig.posed(phase_index)

    return posed


def _frame_rows(store: Store, model, seq_id: str, frame_index: int) -> list:
    """The rows of one frame of a per-sequence table (filtered in Arrow before validation)."""
    import pyarrow.compute as pc

    from carlaocc.catalog.parquet import from_table

    table = ParquetTable(store, model).load_arrow([seq_id])
    return from_table(model, table.filter(pc.equal(table["frame_index"], frame_index)))


@dataclasses.dataclass(frozen=True)
class FrameInputs:
    """What one frame's tasks read: its sequence, frame and actor rows and the panoptic scene."""

    sequence: SequenceRecord
    frame: FrameRecord
    actors: list[ActorStateRecord]
    scene: list  # SceneMesh, LiDAR frame, cut to the requested region


def frame_inputs(store: Store, seq_id: str, frame_index: int, region) -> FrameInputs:
    """The rows and panoptic scene (LiDAR frame, cut to ``region`` = (lo, hi)) of one frame."""
    from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame, frame_region

    t_seq = ParquetTable(store, SequenceRecord)
    sequences = t_seq.load([seq_id]) if t_seq.exists(seq_id) else []
    if not sequences:
        raise StoreError(f"sequence {seq_id!r} is not in {store.url}: run the scenes stage first")
    (sequence,) = sequences
    frames = _frame_rows(store, FrameRecord, seq_id, frame_index)
    if not frames:
        raise StoreError(f"sequence {seq_id} has no frame {frame_index} (it has {sequence.frame_count})")
    actors = _frame_rows(store, ActorStateRecord, seq_id, frame_index)
    # the town's placement index, kept per worker while the placements file is unchanged (its
    # per-asset preparation of big stuff meshes is then reused across frames)
    t_place = ParquetTable(store, PlacementRecord)
    key = f"town={sequence.town}"
    index = _cached(_INDEX_CACHE, (store.url, key, store.fingerprint(t_place.path(key))),
                    lambda: PlacementIndex(t_place.load([key])), 8)
    # geometry of the placements whose world AABB meets the frame's region, and of the actors
    selected = index.select(*frame_region(frames[0], *region))
    needed = {index.placements[i].asset_id for i in selected} | {a.asset_id for a in actors}
    geometry = load_geometry(store, needed, index.placements)
    scene = assemble_frame(frames[0], actors, index, geometry, region,
                           pedestrian_geometry=pedestrian_geometry(geometry), ego_asset_id=sequence.ego_asset_id)
    return FrameInputs(sequence, frames[0], actors, scene)


def frame_scene(store: Store, seq_id: str, frame_index: int, region) -> list:
    """The panoptic scene (list of SceneMesh, LiDAR frame) of one frame, cut to ``region`` =
    (lo, hi) in the LiDAR frame."""
    return frame_inputs(store, seq_id, frame_index, region).scene


def occupancy_arrays(cfg: VoxelizeConfig) -> tuple[str, ...]:
    """The occupancy arrays the voxelize stage writes under ``cfg``."""
    return ("semantic", "instance") + (("mask_camera", "mask_lidar") if cfg.masks else ()) + (
        ("flow",) if cfg.flow else ())


def _frame_flow(inputs: FrameInputs):
    """``(tile, tile_origin, voxel_size) -> (flat indices, float16 (N, 3) flow) | None``: the flow
    of the voxels of the frame's actors in a tile (None when it holds none: its flow is zero)."""
    from carlaocc.stages.geometry import pose_from_list
    from carlaocc.stages.voxelize.flow import actor_voxels, voxel_flow

    actors = [a for a in inputs.actors if a.instance_id > 0]
    ids = np.asarray([a.instance_id for a in actors], dtype=np.uint32)
    # rotation centre: the actor's pose origin (its velocity is that point's, see traffic)
    centres = np.asarray([pose_from_list(a.pose)[:3, 3] for a in actors], dtype=np.float64).reshape(-1, 3)
    vel = np.asarray([a.velocity for a in actors], dtype=np.float64).reshape(-1, 3)
    ang = np.asarray([a.angular_velocity for a in actors], dtype=np.float64).reshape(-1, 3)
    lidar_to_world = pose_from_list(inputs.frame.lidar_pose)

    def flow(tile, tile_origin, voxel_size):
        # an actor's voxels are looked for only inside the boxes of its meshes in the tile
        flat, actor = actor_voxels(tile.instance, tile.things, ids)
        if len(flat) == 0:
            return None
        return flat, voxel_flow(flat, tile.instance.shape, tile_origin, voxel_size, actor, centres, vel, ang,
                                lidar_to_world)

    return flow


def _tile_chunk_flags(shape: tuple[int, ...], cx: int, cy: int) -> np.ndarray:
    """All-false chunk flags (x chunks, y chunks) of a tile of ``shape`` (X, Y, ...)."""
    return np.zeros((-(-shape[0] // cx), -(-shape[1] // cy)), dtype=bool)


def _box_chunks(things: np.ndarray, shape: tuple[int, ...], cx: int, cy: int) -> np.ndarray:
    """Chunk flags (x chunks, y chunks) of the chunks of a tile of ``shape`` that the voxel boxes
    ``things`` (Tile.things rows: instance, i0, i1, j0, j1, k0, k1) reach: where the instance
    tile can be nonzero."""
    flags = _tile_chunk_flags(shape, cx, cy)
    for _, i0, i1, j0, j1, k0, k1 in things:
        if i1 > i0 and j1 > j0 and k1 > k0:
            flags[i0 // cx:(i1 - 1) // cx + 1, j0 // cy:(j1 - 1) // cy + 1] = True
    return flags


def _index_chunks(flat: np.ndarray, shape: tuple[int, ...], cx: int, cy: int) -> np.ndarray:
    """Chunk flags (x chunks, y chunks) of the chunks holding the C-order voxel indices ``flat``
    of a tile of ``shape`` (X, Y, Z)."""
    flags = _tile_chunk_flags(shape, cx, cy)
    flags[flat // (shape[1] * shape[2]) // cx, (flat // shape[2]) % shape[1] // cy] = True
    return flags


def voxelize_task(store: Store, cfg: VoxelizeConfig, part: Partition) -> dict[str, str]:
    """Voxelize one frame of one sequence at one resolution into occupancy.zarr: semantic,
    instance and flow tile by tile (x-slabs of whole chunks), then the camera and LiDAR masks,
    traced through the frame's occupancy packed tile by tile and written chunk by chunk from
    their bits (no array of the whole frame is ever held)."""
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.scenes.assembly import region_of_grid
    from carlaocc.stages.scratch import scratch
    from carlaocc.stages.voxelize import voxelize_tiles
    from carlaocc.stages.voxelize.visibility import camera_visibility_bits, lidar_visibility_bits, pack_occupancy

    seq_id, frame_index = part.params["sequence_id"], part.params["frame_index"]
    grid = cfg.grid(part.params["resolution"])
    inputs = frame_inputs(store, seq_id, frame_index, region_of_grid(grid))
    occ = OccupancyStore(store)
    names = occupancy_arrays(cfg)
    tile_x = cfg.chunk_edge * cfg.tile_chunks
    cx, cy = occ.chunk_edges(seq_id, grid, "instance")
    flow = _frame_flow(inputs) if cfg.flow else None
    packed = pack_occupancy(None, grid, reuse=True) if cfg.masks else None
    vs = float(grid.voxel_size)
    # 1. per tile: semantic, instance (only the chunks its things' boxes reach are read), flow,
    #    and the tile's occupancy packed for the masks
    for tile in voxelize_tiles(inputs.scene, grid, tile_x, cfg.fill):
        nx = tile.semantic.shape[0]
        occ.write_tile(seq_id, grid, frame_index, "semantic", tile.semantic, tile.x0)
        shape = tile.instance.shape
        occ.write_tile(seq_id, grid, frame_index, "instance", tile.instance, tile.x0,
                       _box_chunks(tile.things, shape, cx, cy))
        if packed is not None:
            packed.pack_slab(tile.x0, tile.semantic)
        if flow is None:
            continue
        v = flow(tile, (grid.origin[0] + tile.x0 * vs, grid.origin[1], grid.origin[2]), vs)
        if v is None:
            occ.clear_tile(seq_id, grid, frame_index, "flow", tile.x0, nx)
            continue
        # a sparse scatter into a zero buffer kept zero between uses (a dense tile is 200 MB at
        # 0.05 m: zeroing it per tile costs more than the flow)
        flat, values = v
        buf = scratch("tile_flow", tile.instance.size * 3, np.float16).reshape(-1, 3)
        try:
            buf[flat] = values
            occ.write_tile(seq_id, grid, frame_index, "flow", buf.reshape(*shape, 3), tile.x0,
                           _index_chunks(flat, shape, cx, cy))
        finally:
            buf[flat] = 0
    # 2. visibility: rays of the rig's LiDAR and cameras through the frame's occupancy, each
    #    mask's chunks unpacked from its bits one at a time (an empty one is known from its words)
    if packed is not None:
        rig = cfg.rig or RigConfig()
        X, Y = packed.shape[:2]
        for name, bits in (("mask_lidar", lidar_visibility_bits(packed, rig)),
                           ("mask_camera", camera_visibility_bits(packed, rig, cfg.camera_ray_stride))):
            occ.write_chunks(seq_id, grid, frame_index, name, 0, X, lambda ci, cj, bits=bits: packed.block(
                bits, ci * cx, cj * cy, min(cx, X - ci * cx), min(cy, Y - cj * cy)))
    return occ.fingerprints(seq_id, grid, frame_index, names)


# -- sensors --------------------------------------------------------------------------------------
def sensor_region(cfg: SensorsConfig) -> tuple[np.ndarray, np.ndarray]:
    """The LiDAR-frame box whose scene the sensors see: ``scene_range`` around the LiDAR
    horizontally, 20 m below to ``scene_range / 2`` above it."""
    r = float(cfg.scene_range)
    return np.array([-r, -r, -20.0]), np.array([r, r, max(r / 2.0, 20.0)])


def sensor_arrays(cfg: SensorsConfig) -> tuple[str, ...]:
    """The camera arrays the sensors stage writes under ``cfg`` (the recorded path reads the raw
    ones, written by the recorder, and never writes them)."""
    from carlaocc.catalog.sensors import CAMERA_MAPS

    raw = ("depth_raw", "semantic_raw", "instance_raw") if cfg.source == "raycast" else ()
    return CAMERA_MAPS + raw


def _recorded_raw(sensors, seq_id: str, frame_index: int, cam) -> "CameraMaps":
    """The raw maps a recorder wrote for one camera and frame (depth_raw and semantic_raw are
    required, instance_raw optional), with a clear error naming what is missing."""
    from carlaocc.stages.sensors import CameraMaps

    def read(name: str, required: bool):
        # a stored chunk is the recorder's image (an all-zero image has no chunk: for depth and
        # semantics of a road camera that is a frame the recorder did not write)
        if sensors.exists(seq_id, cam.name, name, frame_index):
            return sensors.read_image(seq_id, cam.name, frame_index, name)
        if required:
            raise StoreError(f"sensors.source is 'recorded' but sensors.zarr/{sensors.array_path(seq_id, cam.name, name)} "
                             f"has no frame {frame_index}: a recorder must write depth_raw and semantic_raw "
                             f"(see README, 'Recorded sensor input')")
        return None

    return CameraMaps(read("depth_raw", True).astype(np.float32, copy=False),
                      read("semantic_raw", True).astype(np.uint8, copy=False), read("instance_raw", False))


def sensors_task(store: Store, cfg: SensorsConfig, part: Partition) -> dict[str, str]:
    """Camera maps and LiDAR of one frame into sensors.zarr and lidar/: the raycast path renders
    clean maps, simulates the raw ones and rectifies them; the recorded path rectifies the raw
    maps already in sensors.zarr. Both write the rectified depth/semantic/instance, the D2NT
    normals and a rectification record per camera."""
    from carlaocc.catalog.sensors import LidarStore, SensorStore
    from carlaocc.schemas.records import RectificationRecord
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.sensors import recorded_stats, rectify_cameras, simulate_frame
    from carlaocc.stages.threads import kernel_threads

    seq_id, frame_index = part.params["sequence_id"], part.params["frame_index"]
    rig = cfg.rig or RigConfig()
    inputs = frame_inputs(store, seq_id, frame_index, sensor_region(cfg))
    sensors = SensorStore(store)
    cams = cfg.selected_cameras(rig)
    outputs: dict[str, str] = {}
    if cfg.source == "raycast":
        frame = simulate_frame(inputs.scene, rig, cfg, nthreads=kernel_threads())
        per_camera = {name: (cf.rectification, cf.normal, cf.raw, cf.stats) for name, cf in frame.cameras.items()}
    else:
        raw = {cam.name: _recorded_raw(sensors, seq_id, frame_index, cam) for cam in cams}
        rect = rectify_cameras(inputs.scene, rig, cfg, raw, nthreads=kernel_threads())
        per_camera = {name: (r, n, raw[name], recorded_stats(name, r, raw[name])) for name, (r, n) in rect.items()}
        frame = None
    records = []
    for cam in cams:
        rect, normal, raw, stats = per_camera[cam.name]
        images = {"depth": rect.maps.depth, "semantic": rect.maps.semantic, "normal": normal.astype(np.float16)}
        if rect.maps.instance is not None:
            images["instance"] = rect.maps.instance
        if cfg.source == "raycast":
            images.update(depth_raw=raw.depth, semantic_raw=raw.semantic, instance_raw=raw.instance)
        for name, data in images.items():
            sensors.write_image(seq_id, cam.name, frame_index, name, data)
        outputs.update(sensors.fingerprints(seq_id, cam.name, frame_index, tuple(images)))
        records.append(RectificationRecord(sequence_id=seq_id, frame_index=frame_index, source=cfg.source,
                                           **dataclasses.asdict(stats)))
    if frame is not None and frame.lidar is not None:
        lidar = LidarStore(store)
        meta = {"lidar_to_world": inputs.frame.lidar_pose, "timestamp": inputs.frame.timestamp,
                "channels": rig.lidar.channels, "range_m": rig.lidar.range_m}
        outputs[lidar.path(seq_id, frame_index)] = lidar.save(seq_id, frame_index, frame.lidar, meta)
    table = ParquetTable(store, RectificationRecord)
    key = f"{seq_id}/{frame_index:04d}"
    outputs[table.path(key)] = table.save(key, records)
    return outputs


# -- metrics --------------------------------------------------------------------------------------
def metrics_task(store: Store, cfg: MetricsConfig, part: Partition) -> dict[str, str]:
    """Spatial continuity per frame and per sequence, per class counts, and temporal consistency
    per frame pair and per sequence, into metrics/.

    Temporal consistency warps each frame t+1 into frame t with the frames' LiDAR poses (the grids
    are in the LiDAR frame; ``scenes/frames``). Its visibility mask is ``mask_camera | mask_lidar``
    (observed by any sensor of the rig): whichever of the two arrays the sequence has; no mask
    when it has neither."""
    from carlaocc.stages.metrics import (column_ranges, sequence_continuity, sequence_temporal, spatial_continuity_counts,
                                temporal_consistency_counts)

    seq_id, res = part.params["sequence_id"], part.params["resolution"]
    grid = GridSpec.model_validate(part.params["grid"])
    occ = OccupancyStore(store)
    arr = occ.open(seq_id, grid, "semantic")
    n_frames = arr.shape[0]
    # LiDAR-to-world pose of every frame
    poses = {f.frame_index: np.asarray(f.lidar_pose, dtype=np.float64).reshape(4, 4)
             for f in ParquetTable(store, FrameRecord).load([seq_id])}
    missing = [t for t in range(n_frames) if t not in poses]
    if missing and n_frames > 1:
        raise StoreError(f"sequence {seq_id}: no LiDAR pose for frame(s) {missing[:5]} in scenes/frames; "
                         f"re-run the scenes stage")
    masks = [n for n in ("mask_camera", "mask_lidar") if occ.exists(seq_id, grid, n)]

    def read(name: str, t: int) -> np.ndarray:
        return occ.read_frame(seq_id, grid, t, (name,))[name]

    def observed(t: int) -> np.ndarray | None:
        if not masks:
            return None
        # the stored masks are uint8 0/1: viewed as bool, OR-ed in place (no 0.05 m temporaries)
        out = read(masks[0], t).view(np.bool_)
        for name in masks[1:]:
            np.logical_or(out, read(name, t).view(np.bool_), out=out)
        return out

    def continuity_row(counts, t: int | None) -> QualityRecord:
        occupied, isolated = int(counts.occupied[1:].sum()), int(counts.isolated[1:].sum())
        return QualityRecord(sequence_id=seq_id, resolution=res, frame_index=t, metric="spatial_continuity",
                             value=counts.score, occupied=occupied, isolated=isolated,
                             numerator=occupied - isolated, denominator=occupied)

    def temporal_row(counts, t: int | None) -> QualityRecord:
        return QualityRecord(sequence_id=seq_id, resolution=res, frame_index=t, metric="temporal_consistency",
                             value=counts.score, numerator=counts.total_intersection,
                             denominator=counts.total_union)

    per_frame, per_pair = [], []
    quality, classes = [], []
    prev = None  # (semantic, observed mask, column ranges) of frame t - 1
    for t in range(n_frames):
        sem = read("semantic", t)
        counts = spatial_continuity_counts(sem)
        per_frame.append(counts)
        quality.append(continuity_row(counts, t))
        for c in np.flatnonzero(counts.occupied):
            classes.append(ClassQualityRecord(sequence_id=seq_id, resolution=res, frame_index=t,
                                              semantic_id=int(c), occupied=int(counts.occupied[c]),
                                              isolated=int(counts.isolated[c])))
        if n_frames < 2:
            continue
        # each frame's column ranges serve both pairs it belongs to
        cur = (sem, observed(t), column_ranges(sem))
        if prev is not None:
            # the pair (t - 1, t): frame t warped into frame t - 1
            tc = temporal_consistency_counts(prev[0], sem, poses[t - 1], poses[t], grid.voxel_size, grid.origin,
                                             mask_t=prev[1], mask_t1=cur[1], ranges_t=prev[2], ranges_t1=cur[2])
            per_pair.append(tc)
            quality.append(temporal_row(tc, t - 1))
        prev = cur
    quality.append(continuity_row(sequence_continuity(per_frame), None))
    quality.append(temporal_row(sequence_temporal(per_pair), None))
    key = f"{seq_id}/{grid.key}"
    t_q, t_c = ParquetTable(store, QualityRecord), ParquetTable(store, ClassQualityRecord)
    return {t_q.path(key): t_q.save(key, quality), t_c.path(key): t_c.save(key, classes)}
