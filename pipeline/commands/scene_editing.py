"""Scene tools behind ``carlaocc scenes``: the unified town mesh, a frame's panoptic mesh, and
parametric editing (``swap``: new sequences whose actors of one class use other assets).

Like the task bodies, these read through the catalog and call the pure compute of ``stages``.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from carlaocc.catalog.admesh import dedupe_assets
from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.lock import root_lock
from carlaocc.catalog.panoptic import panoptic_glb_bytes
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.tasks.frame import frame_scene, load_geometry
from carlaocc.pipeline.tasks.scenes import is_edited, sequence_skeletons
from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, EgoStateRecord, FrameRecord, PlacementRecord,
                                      RunRecord, SensorPoseRecord, SequenceRecord, SkeletonRecord, TownRecord)
from carlaocc.stages.geometry import box_center, pose_from_list
from carlaocc.stages.scenes.assembly import flatten, town_mesh
from carlaocc.stages.scenes.placing import box_corners_aabb

SWAP_STAGE = "scenes-swap"
LENGTH_TOLERANCE, WIDTH_TOLERANCE, HEIGHT_TOLERANCE = 0.20, 0.15, 0.35  # relative footprint/height difference


def town_mesh_glb(store: Store, town: str) -> tuple[bytes, int, int]:
    """The whole town's static mesh (world frame) as GLB with per-face semantic and instance ids;
    returns (bytes, triangles, placements)."""

    t_place = ParquetTable(store, PlacementRecord)
    if not t_place.exists(f"town={town}"):
        towns = sorted(p.split("town=")[-1][: -len(".parquet")] for p in t_place.paths() if "/town=" in p)
        raise StoreError(f"town {town!r} is not in {store.url} (towns: {', '.join(towns) or 'none; run the scenes stage'})")
    placements = t_place.load([f"town={town}"])
    geometry = load_geometry(store, {p.asset_id for p in placements}, placements)
    mesh = town_mesh(placements, geometry, frozenset(taxonomy.thing_ids(town_label_table(store, town))))
    return panoptic_glb_bytes(*mesh.arrays()), len(mesh.faces), len(placements)


def town_label_table(store: Store, town: str) -> str:
    """The label table a town was built under (its ``towns`` row; ``carlaocc-v1`` before the
    column existed)."""

    t = ParquetTable(store, TownRecord)
    rows = t.load([f"town={town}"]) if t.exists(f"town={town}") else []
    return rows[0].label_table if rows else "carlaocc-v1"


def frame_mesh_glb(store: Store, sequence_id: str, frame_index: int, region) -> tuple[bytes, int]:
    """One frame's panoptic scene (LiDAR frame) cut to ``region`` as GLB; returns (bytes, triangles)."""

    seqs = ParquetTable(store, SequenceRecord)
    town = seqs.load([sequence_id])[0].town if seqs.exists(sequence_id) else ""
    mesh = flatten(frame_scene(store, sequence_id, frame_index, region, town_label_table(store, town)))
    return panoptic_glb_bytes(*mesh.arrays()), len(mesh.faces)


@dataclass(frozen=True)
class SwapResult:
    """One edited sequence: its id, the parent, and how many actor instances and static
    placements got a new asset (and how many kept theirs for want of a compatible one)."""

    sequence_id: str
    parent: str
    swapped: int
    kept: int
    swapped_static: int = 0
    kept_static: int = 0


def compatible(original: AssetRecord, candidates: Sequence[AssetRecord]) -> list[AssetRecord]:
    """Assets of the same class, other than ``original``, whose length, width and height differ
    by at most :data:`LENGTH_TOLERANCE`, :data:`WIDTH_TOLERANCE`, :data:`HEIGHT_TOLERANCE`
    (relative): a replacement keeps the footprint the trajectory was simulated with."""
    l0, w0, h0 = original.extent
    out = []
    for a in candidates:
        if a.asset_id == original.asset_id or a.category_id != original.category_id:
            continue
        l, w, h = a.extent
        if abs(l - l0) <= LENGTH_TOLERANCE * l0 and abs(w - w0) <= WIDTH_TOLERANCE * w0 and abs(h - h0) <= HEIGHT_TOLERANCE * h0:
            out.append(a)
    return sorted(out, key=lambda a: a.asset_id)


def _draw(items, by_id: dict[str, AssetRecord], pool: Sequence[AssetRecord], seed: int,
          stream: int) -> tuple[dict[int, AssetRecord], int]:
    """For (key, asset id) items, a compatible replacement per key drawn from ``seed`` (stream 0:
    actors by instance id, 1: placements by placement id), and how many had none."""
    choice: dict[int, AssetRecord] = {}
    kept = 0
    for key, asset_id in items:
        original = by_id.get(asset_id)
        options = compatible(original, pool) if original is not None else []
        if not options:
            kept += 1
            continue
        entropy = [seed, key] if stream == 0 else [seed, stream, key]  # actors keep their former draws
        rng = np.random.default_rng(np.random.SeedSequence(entropy))
        choice[key] = options[int(rng.integers(len(options)))]
    return choice, kept


def _swapped_placement(p: PlacementRecord, new: AssetRecord | None) -> PlacementRecord:
    """``p`` with ``new`` standing on its lot (same pose: the asset origin is the bottom centre of
    its box), its world AABB that of the new box."""
    if new is None:
        return p

    l, w, h = (float(e) for e in new.extent)
    lo, hi = box_corners_aabb((-l / 2, -w / 2, 0.0), (l / 2, w / 2, h), np.array(p.pose, dtype=np.float64).reshape(4, 4))
    return p.model_copy(update={"asset_id": new.asset_id, "semantic_id": new.category_id, "mesh_path": "",
                                "aabb_min": lo, "aabb_max": hi})


def swap_id(sequence_id: str, category: str, seed: int) -> str:
    return f"{sequence_id}~swap-{category.lower()}-s{seed}"


def swap_class(store: Store, category: str, seed: int, sequences: Sequence[str] | None = None,
               asset_sources: Sequence[str] | None = None) -> list[SwapResult]:  # fmt: skip
    """:func:`swap_class_locked` holding the root's writer lock (:mod:`carlaocc.catalog.lock`: it
    waits for a command writing the root)."""
    with root_lock(store):
        return swap_class_locked(store, category, seed, sequences, asset_sources)


def swap_class_locked(store: Store, category: str, seed: int, sequences: Sequence[str] | None = None,
                      asset_sources: Sequence[str] | None = None) -> list[SwapResult]:  # fmt: skip
    """For every original sequence (or the given ones), write a new sequence in which every
    actor and every static placement (buildings, props, poles...) of ``category`` uses another
    asset of a compatible footprint, drawn per instance / placement from ``seed``; trajectories,
    rig poses, timing, lots and a recorded ego's motion (``ego_states``) are unchanged, boxes take
    the new extent. Swapped placements go to
    the new sequence's own copy of the placements (``SequenceRecord.placements``). A sequence with
    nothing to swap gets no edit; when no sequence has anything to swap, nothing is written and
    StoreError says why. The new sequence's ``parent_sequence_id`` names the original and a
    lineage record (stage ``scenes-swap``) lists the files read and written."""
    try:
        cls = taxonomy.by_name(category)
    except (KeyError, ValueError):
        raise StoreError(f"unknown class {category!r}; classes: {', '.join(c.name for c in taxonomy.CLASSES)}") from None
    t_seq = ParquetTable(store, SequenceRecord)
    all_seqs = {s.sequence_id: s for s in t_seq.load()}
    if sequences:
        missing = [s for s in sequences if s not in all_seqs]
        if missing:
            raise StoreError(f"sequence(s) {', '.join(missing)} not in {store.url}")
        targets = [all_seqs[s] for s in sequences]
    else:
        targets = [s for sid, s in sorted(all_seqs.items()) if not is_edited(sid)]
    if not targets:
        raise StoreError(f"no sequences in {store.url}: run the scenes stage first")
    assets = dedupe_assets(ParquetTable(store, AssetRecord).load())
    if asset_sources:
        assets = [a for a in assets if a.source in asset_sources]
    by_id = {a.asset_id: a for a in assets}
    pool = [a for a in assets if a.category_id == cls.id]
    tables = {
        "frames": ParquetTable(store, FrameRecord),
        "sensor_poses": ParquetTable(store, SensorPoseRecord),
        "actors": ParquetTable(store, ActorStateRecord),
    }
    t_place = ParquetTable(store, PlacementRecord)
    t_skel = ParquetTable(store, SkeletonRecord)
    t_ego = ParquetTable(store, EgoStateRecord)  # a recorded sequence's ego motion: the same ego, copied
    # 1. plan every edit before writing anything: nothing is written when nothing can be swapped
    plans = []
    for parent in targets:
        new_id = swap_id(parent.sequence_id, cls.name, seed)
        actors = tables["actors"].load([parent.sequence_id])
        choice, kept = _draw(sorted({a.instance_id: a.asset_id for a in actors if a.semantic_id == cls.id}.items()),
                             by_id, pool, seed, 0)
        key = parent.placements_key()
        placements = t_place.load([key]) if t_place.exists(key) else []
        statics, kept_static = _draw([(p.placement_id, p.asset_id) for p in placements if p.semantic_id == cls.id],
                                     by_id, pool, seed, 1)
        if choice or statics:
            plans.append((parent, new_id, actors, choice, kept, placements, statics, kept_static))
    if not plans:
        raise StoreError(
            f"nothing to swap: no actor or static placement of class {cls.name} in "
            f"{', '.join(t.sequence_id for t in targets)} has another {cls.name} asset of a compatible footprint "
            f"(length within {LENGTH_TOLERANCE:.0%}, width {WIDTH_TOLERANCE:.0%}, height {HEIGHT_TOLERANCE:.0%}); "
            f"nothing written")
    run_id, _ = LineageLog(store).new_run_id(datetime.now(timezone.utc))
    results, runs = [], []
    for parent, new_id, actors, choice, kept, placements, statics, kept_static in plans:
        started = datetime.now(timezone.utc)
        new_actors = []
        for a in actors:
            new = choice.get(a.instance_id)
            if new is None:
                new_actors.append(a.model_copy(update={"sequence_id": new_id}))
                continue
            l, w, h = (float(e) for e in new.extent)
            # the new box stands on the same pose origin (pitch and roll kept)
            new_actors.append(a.model_copy(update={
                "sequence_id": new_id, "asset_id": new.asset_id, "semantic_id": new.category_id,
                "box_size": [l, w, h], "box_center": box_center(pose_from_list(a.pose), h),
                "scale": 1.0,  # the new asset at its own size (a recorded walker's scale was its cycle's)
            }))  # fmt: skip
        update = {"sequence_id": new_id, "parent_sequence_id": parent.sequence_id, "edit": f"swap {cls.name} seed={seed}"}
        inputs = {t.path(parent.sequence_id): store.fingerprint(t.path(parent.sequence_id))
                  for t in (t_seq, *tables.values())}  # fmt: skip
        outputs = {}
        if statics:
            # the static objects: a copy of the placements with the swapped ones on their lot
            key = f"sequence={new_id}"
            update["placements"] = key
            inputs[t_place.path(parent.placements_key())] = store.fingerprint(t_place.path(parent.placements_key()))
            outputs[t_place.path(key)] = t_place.save(key, [_swapped_placement(p, statics.get(p.placement_id))
                                                            for p in placements])
        outputs[t_seq.path(new_id)] = t_seq.save(new_id, [parent.model_copy(update=update)])
        copied = {name: new_actors if name == "actors" else [
            r.model_copy(update={"sequence_id": new_id}) for r in table.load([parent.sequence_id])]
            for name, table in tables.items()}  # fmt: skip
        for name, table in tables.items():
            outputs[table.path(new_id)] = table.save(new_id, copied[name])
        # the walkers' skeletons: posed anew when pedestrians got other assets, else copied
        if cls.name == "Pedestrian" and choice:
            outputs[t_skel.path(new_id)] = t_skel.save(new_id, sequence_skeletons(store, new_actors, copied["frames"]))
        elif t_skel.exists(parent.sequence_id):
            outputs[t_skel.path(new_id)] = t_skel.save(new_id, [
                r.model_copy(update={"sequence_id": new_id}) for r in t_skel.load([parent.sequence_id])])
        if t_ego.exists(parent.sequence_id):
            inputs[t_ego.path(parent.sequence_id)] = store.fingerprint(t_ego.path(parent.sequence_id))
            outputs[t_ego.path(new_id)] = t_ego.save(new_id, [
                r.model_copy(update={"sequence_id": new_id}) for r in t_ego.load([parent.sequence_id])])
        results.append(SwapResult(new_id, parent.sequence_id, len(choice), kept, len(statics), kept_static))
        runs.append(RunRecord(
            run_id=run_id, stage=SWAP_STAGE, partition=new_id, code_version="", config_hash=f"{cls.name}:{seed}",
            cache_key="", input_fingerprints=json.dumps(inputs, sort_keys=True),
            output_fingerprints=json.dumps(outputs, sort_keys=True), status="completed", started_at=started,
            ended_at=datetime.now(timezone.utc), host=socket.gethostname(),
        ))  # fmt: skip
    LineageLog(store).append(SWAP_STAGE, run_id, runs)
    return results
