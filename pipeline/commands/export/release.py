"""``carlaocc export carlaocc-release``: a dataset in the official CarlaOcc release's layout, so
the release's reader (``tutorials/dataset.py``) and the tools built on it read ours.

What is written under ``OUT`` (formats: :mod:`carlaocc.catalog.formats.carlaocc_release`)::

    calib/calib.yaml, splits/{train,val,test}.txt, carlaocc_export.json
    Town<NN>_Opt_Seq<NN>/occupancy/{vs_0_1, vs_0_2_forward_view, vs_0_4_surround_view}/<frame:04d>.npz
    Town<NN>_Opt_Seq<NN>/poses/lidar.txt
    Town<NN>_Opt_Seq<NN>/{rgb, depth, semantics, normal}/image_XX/<frame:04d>.png   (where built)
    Town<NN>_Opt_Seq<NN>/lidar/<frame:04d>.ply                                     (where built or recorded)

How our dataset maps onto it:

* **Grids.** The three release grids are pooled from the occupancy built at ``--voxel-size``
  (0.1 m, the release's raw voxel size, by default; any size dividing 0.1 m works) with the
  class-priority rule of :func:`carlaocc.stages.voxelize.pooling.pool_window`; at 0.1 m on the
  default region ``vs_0_1`` is our grid voxel for voxel.
* **Towns and sequences.** Our towns get the release's town numbers in order (1..7, 10, then
  11...; a recorded ``TownNN_Opt`` keeps its number); within a town, sequences are numbered in
  traffic-level order (none, low, medium, high; then by id), as the release numbers its
  sequences (00 none, 01-03 low, 04-06 medium, 07+ high for the paper's plan). Numbering is over
  every sequence of the dataset, so exporting a subset keeps the folder names.
* **Labels.** ``semantic * 1000 + instance % 1000`` under the dataset's label table (the
  release's by default). A class whose instance ids would collide under ``% 1000`` in a
  sequence, or reach a multiple of 1000, is renumbered 1, 2, ... for that sequence;
  ``carlaocc_export.json`` maps every exported id back to ours, with the town and sequence maps.
* **Splits.** The dataset's splits (``<root>/splits/``, the splits stage), one line per frame.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from carlaocc.catalog.carla_recording import OPTICAL_FROM_BODY
from carlaocc.catalog.formats import atomic_write
from carlaocc.catalog.formats import carlaocc_release as rel
from carlaocc.catalog.formats.carlaocc_npz import LABEL_ENCODINGS, save_carlaocc_npz
from carlaocc.catalog.formats.manifest import grid_manifest, save_grid_manifest, save_split_lists
from carlaocc.catalog.images import png_bytes
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sensors import LidarStore, RecordedLidarStore, SensorStore
from carlaocc.catalog.splits import SPLIT_NAMES
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.formats.carlaocc_release import release_grid_spec
from carlaocc.pipeline.commands.export.spec import (ExportFormat, ExportJob, actor_ids, one_label_table,
                                                    sequence_release_ids, sequence_splits, voxelized_or_refuse)
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import FrameRecord, SequenceRecord
from carlaocc.schemas.taxonomy import palette
from carlaocc.stages.sensors import camera_poses
from carlaocc.stages.voxelize.pooling import pool_window

LEVEL_ORDER = {"none": 0, "low": 1, "medium": 2, "high": 3}


def folder_names(seqs: list[SequenceRecord]) -> tuple[dict[str, int], dict[str, tuple[int, int]]]:
    """``(town -> release town number, sequence id -> (town number, sequence number))`` over every
    sequence of the dataset (see the module docstring). A recorded sequence whose id ends in the
    release's folder name (``town00_Town03_Opt_Seq04``) keeps that town and sequence number."""
    towns = sorted({s.town for s in seqs})
    # recorded towns: the number their sequences' ids carry
    recorded: dict[str, str] = {}
    for s in seqs:
        m = re.search(r"(Town\d{2}(?:HD)?_Opt)_Seq\d{2}$", s.sequence_id)
        if m:
            recorded.setdefault(s.town, m.group(1))
    names = [recorded.get(t, t) for t in towns]
    by_name = rel.town_numbers(names)
    numbers = {t: by_name[n] for t, n in zip(towns, names)}
    out: dict[str, tuple[int, int]] = {}
    for town in towns:
        mine = sorted((s for s in seqs if s.town == town), key=lambda s: (LEVEL_ORDER[s.traffic_level], s.sequence_id))
        taken = set()
        for s in mine:
            m = re.search(r"_Seq(\d{2})$", s.sequence_id) if town in recorded else None
            if m and int(m.group(1)) not in taken:
                out[s.sequence_id] = (numbers[town], int(m.group(1)))
                taken.add(int(m.group(1)))
        free = (k for k in range(100) if k not in taken)
        for s in mine:
            if s.sequence_id not in out:
                k = next(free, None)
                if k is None:
                    raise StoreError(f"town {town} has {len(mine)} sequences; the release's folder names hold 100 "
                                     f"(Seq00-Seq99)")
                out[s.sequence_id] = (numbers[town], k)
    return numbers, out


def _write_images(store: Store, seq: str, frame: int, folder: Path) -> int:
    """The frame's camera maps in the release's encodings; returns the files written."""
    sensors = SensorStore(store)
    n = 0
    encoders = {"rgb": ("rgb", lambda a: a), "depth": ("depth", rel.encode_depth),
                "semantic": ("semantics", lambda a: rel.encode_semantics(a, palette())),
                "normal": ("normal", rel.encode_normals)}  # fmt: skip
    for cam in sensors.cameras(seq):
        image = f"image_{cam.rsplit('_', 1)[-1]}"
        for name, (sub, encode) in encoders.items():
            # the array, not the frame's chunk: an all-zero image has no chunk and is still an image
            if not sensors.exists(seq, cam, name):
                continue
            data = png_bytes(encode(sensors.read_image(seq, cam, frame, name)))
            atomic_write(folder / sub / image / f"{frame:04d}.png", lambda fh, d=data: fh.write(d))
            n += 1
    return n


def write_lidar(store: Store, seq: str, frame: int, folder: Path) -> int:
    """The frame's scan as ``lidar/<frame>.ply``: our ray-cast one, else (a recorded frame) the
    recording's own ``lidar/`` scan as kept in lidar_recorded/ (scan 0: CARLA's ray_cast LiDAR,
    which is what the release's ``lidar/`` holds)."""
    lidar, recorded = LidarStore(store), RecordedLidarStore(store)
    intensity = None
    if lidar.exists(seq, frame):
        pts = lidar.load(seq, frame)
    elif recorded.exists(seq, frame):
        pts = recorded.load(seq, frame)
        pts = {c: v[pts["scan"] == 0] for c, v in pts.items()}
        intensity = pts["intensity"]
    else:
        return 0
    text = rel.ply_text(np.column_stack([pts["x"], pts["y"], pts["z"]]), intensity)
    atomic_write(folder / "lidar" / f"{frame:04d}.ply", lambda fh: fh.write(text.encode()))
    return 1


def _calib(config: DatasetConfig) -> str:
    """``calib.yaml`` of the rig: the release's camera names (``cam_XX``) and body frames."""
    rig = config.scenes.rig
    cams = list(rig.cameras)
    odd = [c.name for c in cams if not re.fullmatch(r"camera_\d{2}", c.name)]
    if odd:
        raise StoreError(f"the release names cameras cam_00..cam_NN; rename the rig's {', '.join(odd)} (camera_NN)")
    if len({(c.width, c.height, c.hfov_deg) for c in cams}) != 1:
        raise StoreError("calib.yaml holds one camera size and field of view; the rig's cameras differ")
    optical = camera_poses(rig)
    body = {c.name.replace("camera_", "cam_"): optical[c.name] @ np.linalg.inv(OPTICAL_FROM_BODY) for c in cams}
    c0 = cams[0]
    return rel.calib_yaml(c0.width, c0.height, c0.hfov_deg, np.asarray(c0.intrinsics), body)


NOTE = "carlaocc_export.json"


def _previous_note(out: Path) -> dict:
    """The note of an earlier export into ``out`` (sequences are added to it), or an empty one;
    StoreError for a note of another format, label table or encoding."""
    path = out / NOTE
    if not path.is_file():
        return {}
    try:
        note = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{path}: unreadable ({exc}); remove it or export into an empty folder") from None
    return note if isinstance(note, dict) else {}


def write_release(job: ExportJob) -> tuple[int, int, int]:
    """Write the release layout under ``job.out`` from the occupancy built at ``job.voxel_size``
    with labels in ``job.options["encoding"]``; returns ``(sequences, frames, files)``. Files are
    written atomically, one frame at a time; exporting more sequences into the same folder adds
    them (the splits, the calibration and ``carlaocc_export.json`` cover every sequence exported
    there)."""
    store, config, out, encoding = job.store, job.config, job.out, job.options["encoding"]
    todo = voxelized_or_refuse(store, job.voxel_size, job.sequences)
    occ = OccupancyStore(store)
    records = {s.sequence_id: s for s in ParquetTable(store, SequenceRecord).load()}
    numbers, folders = folder_names(list(records.values()))
    splits = sequence_splits(store, [s for s, _, _ in todo])
    grids = [(g, release_grid_spec(g)) for g in rel.RELEASE_GRIDS]
    table_name = one_label_table(store, {s: g for s, g, _ in todo})
    # an earlier export into the same folder: same table and encoding, then its sequences stay
    note = _previous_note(job.target)
    for key, value in (("format", "carlaocc-release"), ("label_table", table_name), ("encoding", encoding)):
        if note and note.get(key) != value:
            raise StoreError(f"{job.target / NOTE}: an export with {key} {note.get(key)!r} is there, this one is {value!r}: "
                             f"export into another folder")
    note = {"format": "carlaocc-release", "label_table": table_name, "encoding": encoding,
            "labels": rel.ENCODING_TEXT[encoding], "towns": note.get("towns", {}), "sequences": note.get("sequences", {}),
            "instances": note.get("instances", {})}  # fmt: skip
    t_frames = ParquetTable(store, FrameRecord)
    n_files = n_frames = 0
    for seq, grid, frame_count in todo:
        town_no, seq_no = folders[seq]
        folder = out / rel.sequence_folder(town_no, seq_no)
        rec = records[seq]
        # 1. poses: every frame has one, or the release's reader fails on the frame
        frames = {f.frame_index: np.asarray(f.lidar_pose, np.float64).reshape(4, 4) for f in t_frames.load([seq])}
        missing = [t for t in range(frame_count) if t not in frames]
        if missing:
            raise StoreError(f"{seq}: no LiDAR pose for frame {missing[0]} in the frames table: re-run the scenes stage")
        text = rel.pose_lines({t: frames[t] for t in range(frame_count)})
        atomic_write(folder / "poses" / "lidar.txt", lambda fh, b=text.encode(): fh.write(b))
        n_files += 1
        # 2. the sequence's exported instance ids, from every frame (actors are the moving ones)
        ids = sequence_release_ids(occ, seq, grid, frame_count, actor_ids(store, seq), encoding)
        keys, vals = rel.instance_lookup(ids)
        # 3. per frame: the three grids (class priority of the release's sem_z_order), camera maps, LiDAR
        for t in range(frame_count):
            data = occ.read_frame(seq, grid, t, ("semantic", "instance"))
            sem, inst = data["semantic"], rel.remap_instances(data["semantic"], data["instance"], keys, vals)
            for g, spec in grids:
                s_c, i_c = pool_window(sem, inst, grid, spec, rel.RELEASE_PRIORITY)
                save_carlaocc_npz(folder / "occupancy" / g.name / f"{t:04d}.npz", s_c, i_c, g.voxel_size,
                                  g.voxel_origin, encoding)
                n_files += 1
            n_files += _write_images(store, seq, t, folder) + write_lidar(store, seq, t, folder)
            n_frames += 1
            job.advance()
        note["towns"][rec.town] = {"number": f"{town_no:02d}", "folder": rel.sequence_folder(town_no, 0)[:-6]}
        note["sequences"][seq] = {"folder": rel.sequence_folder(town_no, seq_no), "split": splits[seq],
                                  "frames": frame_count, "rate_hz": rec.rate_hz}
        note["instances"][seq] = {f"{s}:{i}": v for (s, i), v in sorted(ids.items())}
    # 4. what holds for the whole export: splits of every sequence exported here, calibration, note
    lines: dict[str, list[str]] = {split: [] for split in SPLIT_NAMES}
    for info in sorted(note["sequences"].values(), key=lambda v: v["folder"]):
        town_no, seq_no = int(info["folder"][4:6]), int(info["folder"][-2:])
        lines[info["split"]] += rel.split_lines(town_no, seq_no, range(info["frames"])).splitlines()
    save_split_lists(out, lines)
    atomic_write(out / "calib" / "calib.yaml", lambda fh: fh.write(_calib(config).encode()))
    atomic_write(out / NOTE, lambda fh: fh.write(json.dumps(note, indent=1).encode()))
    # grid.json: the three grids each frame's files index (LiDAR frame, the release's origins)
    labels = [c.name for c in taxonomy.label_table(table_name).classes]
    grids = [{"folder": g.name, "voxel_size": g.voxel_size, "origin": g.voxel_origin, "shape": g.volume_size}
             for g in rel.RELEASE_GRIDS]
    save_grid_manifest(out, grid_manifest("carlaocc-release", "lidar", grids, labels, 0, table_name, encoding=encoding))
    return len(todo), n_frames, n_files + len(SPLIT_NAMES) + 3


FORMATS = (
    ExportFormat("carlaocc-release", "the official release's layout: Town<NN>_Opt_Seq<NN>/occupancy/{vs_0_1, "
                 "vs_0_2_forward_view, vs_0_4_surround_view}, poses, calib, splits, camera maps, LiDAR",
                 write_release, options={"encoding": LABEL_ENCODINGS}, default_voxel_size=0.1),
)
