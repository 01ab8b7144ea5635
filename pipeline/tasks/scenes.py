"""The scenes stage: one task per town builds the town (procedural styles or OpenDRIVE), places
its static objects, simulates its traffic and ego sequences, and writes the town's stuff meshes,
placements, town row, sequences, frames, sensor poses and actors. A recorded town
(``carla-recording``) is read from its recording instead (:mod:`carlaocc.pipeline.tasks.recording`).
"""

from __future__ import annotations

from carlaocc.catalog.admesh import dedupe_assets
from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.meshes import MeshStore
from carlaocc.catalog.opendrive import read_opendrive
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.towns import resolve_opendrive
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.frame import load_geometry, pedestrian_rigs
from carlaocc.pipeline.tasks.partitions import INGEST_PARTITION, town_key
from carlaocc.pipeline.tasks.recording import recorded_scenes, recording_files
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, FrameRecord, PlacementRecord, QuarantineRecord,
                                      SensorPoseRecord, SequenceRecord, SkeletonRecord, TownRecord,
                                      EgoStateRecord)
from carlaocc.stages.scenes import build_town, simulate_town
from carlaocc.stages.scenes.people.pedestrians import match_walker_phases
from carlaocc.stages.scenes.people.skeletons import skeleton_rows



def _town_files(spec) -> tuple[str, ...]:
    """Input files of a town (its OpenDRIVE file, its recording's poses and traffic),
    fingerprinted with the partition."""
    if spec.recording is not None:
        return recording_files(spec)
    if spec.opendrive is None:
        return ()

    try:
        return (str(resolve_opendrive(spec.opendrive)),)
    except (FileNotFoundError, ValueError) as exc:
        raise StoreError(f"town opendrive file: {exc}") from None


def scenes_partitions(ctx: Context) -> list[Partition]:
    """One per town; each reads the library of the configured asset sources (the procedural
    partition and every ingested item of the other sources) and its OpenDRIVE file."""
    sources = ctx.config.scenes.asset_sources
    needs = [("ingest", INGEST_PARTITION)] if "procedural" in sources else []
    # recorded towns place the models `carlaocc ingest carla-recording` made
    recorded = ("carla-recording",) if any(t.style == "carla-recording" for t in ctx.config.scenes.towns) else ()
    others = tuple(s for s in sources if s != "procedural") + tuple(r for r in recorded if r not in sources)
    if others:
        latest = LineageLog(ctx.store).latest("ingest")
        needs += [("ingest", k) for k, r in sorted(latest.items())
                  if r.status == "completed" and k.split(":")[0] in others]
    return [Partition(town_key(i), {"town_index": i}, needs=tuple(needs), files=_town_files(spec))
            for i, spec in enumerate(ctx.config.scenes.towns)]


def scenes_config(config) -> ScenesConfig:
    """The scenes stage's config: ``scenes`` with the dataset's taxonomy (which placed classes
    get instance ids)."""
    return config.scenes.model_copy(update={"taxonomy": config.taxonomy})


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

    return read_opendrive(resolve_opendrive(spec.opendrive))


def sequence_skeletons(store: Store, actors, frames) -> list:
    """The ``skeletons`` rows of one sequence (see :func:`carlaocc.stages.scenes.people.skeletons.skeleton_rows`):
    pedestrian rigs built from their ADMesh geometry (the per-worker cache the frames use)."""

    ped = taxonomy.by_name("Pedestrian").id
    ids = {a.asset_id for a in actors if a.semantic_id == ped}
    return skeleton_rows(actors, frames, pedestrian_rigs(load_geometry(store, ids, []) if ids else {}))


def is_edited(sequence_id: str) -> bool:
    """Edited sequences (``scenes swap``) carry a ``~`` in their id; re-simulating their town
    removes them, since their trajectories are copies of the old simulation."""
    return "~" in sequence_id


def scenes_task(store: Store, cfg: ScenesConfig, part: Partition) -> dict[str, str]:
    """Build one town and simulate its sequences; write stuff meshes, placements, the town row,
    sequences, frames, sensor poses and actors."""

    index = part.params["town_index"]
    spec = cfg.towns[index]
    outputs: dict[str, str] = {}
    t_quarantine = ParquetTable(store, QuarantineRecord)
    if spec.style == "carla-recording":
        recorded = recorded_scenes(store, cfg, spec, index, town_key(index))
        town = recorded.town
        assets = ParquetTable(store, AssetRecord).load()
        results = [(r.sequence, r.frames, r.sensor_poses, r.actors, r.skeletons, r.ego_states) for r in recorded.sequences]
        # what had to be left out, queryable: SELECT * FROM quarantine WHERE stage = 'scenes'
        rows = [QuarantineRecord(stage="scenes", source="carla-recording", source_path=where, reason=why[:200],
                                 hint=why) for where, why in recorded.skipped]  # fmt: skip
        key = f"scenes-{town.name}"
        if rows:
            outputs[t_quarantine.path(key)] = t_quarantine.save(key, rows)
        else:
            store.remove(t_quarantine.path(key))
    else:
        assets = scene_assets(store, cfg)
        town = build_town(spec, cfg, index, assets, read_town_network(spec), spec.opendrive or "")
        results = None
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
        bounds=[float(v) for v in town.bounds], label_table=taxonomy.label_table(cfg.taxonomy).name,
    )  # fmt: skip
    outputs[t_town.path(key)] = t_town.save(key, [row])

    tables = {
        "sequence": ParquetTable(store, SequenceRecord),
        "frames": ParquetTable(store, FrameRecord),
        "sensor_poses": ParquetTable(store, SensorPoseRecord),
        "actors": ParquetTable(store, ActorStateRecord),
        "skeletons": ParquetTable(store, SkeletonRecord),
        "ego_states": ParquetTable(store, EgoStateRecord),
    }
    written = set()
    if results is None:
        results = [(seq.sequence, seq.frames, seq.sensor_poses, seq.actors, sequence_skeletons(store, seq.actors, seq.frames),
                    None) for seq in simulate_town(cfg, spec, town, assets, match_phases=match_walker_phases)]  # fmt: skip
    for sequence, frames, sensor_poses, actors, skeletons, ego_states in results:
        sid = sequence.sequence_id
        written.add(sid)
        rows = {"sequence": [sequence], "frames": frames, "sensor_poses": sensor_poses, "actors": actors,
                "skeletons": skeletons, "ego_states": ego_states}
        for name, table in tables.items():
            if rows[name] is None:  # a simulated ego has no recorded motion: no file (an old one goes)
                store.remove(table.path(sid))
                continue
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
    # so do the placement copies of edited sequences that swapped static objects of this town
    for rel in t_place.paths():
        key = rel[len(t_place.dir) + 1 : -len(".parquet")]
        if key.startswith(f"sequence={town.name}_") and is_edited(key[len("sequence="):]):
            store.remove(rel)
    return outputs


SPEC = StageSpec(
    name="scenes",
    description="towns (procedural styles, OpenDRIVE), traffic, ego sequences, rig poses, actors",
    upstream=("ingest",),
    reads=("admesh/assets/", "admesh/parts/", "admesh/meshes/"),
    writes=("scenes/meshes/", "scenes/placements/", "scenes/towns/", "scenes/sequences/", "scenes/frames/",
            "scenes/sensor_poses/", "scenes/actors/", "scenes/skeletons/", "scenes/ego_states/ (recorded sequences)",
            "admesh/quarantine/scenes-<town>.parquet (recorded towns: what was left out)"),
    partitions=scenes_partitions,
    task=scenes_task,
    config_of=scenes_config,
)
