"""``carlaocc-npz``: ``<sequence>/<frame:06d>.npz`` -- our own grid at the exported voxel size,
rows (x, y, z, label) with the label ``semantic << 11 | instance`` as the release's code writes
and reads it (``--label-encoding decimal``: ``semantic * 1000 + instance``, the release's
documentation), instance ids stable across the sequence and unique within a class (placed
objects 1..999, moving ones ``1000 + id % 1000``, renumbered in id order where those would
collide; ``<sequence>/instances.json`` maps ``"class:id"`` back to ours). More instances than the
encoding holds is refused (clear error) rather than wrapped.
"""

from __future__ import annotations

import json

from carlaocc.catalog.formats import atomic_write, save_carlaocc_npz
from carlaocc.catalog.formats.carlaocc_npz import LABEL_ENCODINGS
from carlaocc.catalog.formats.carlaocc_release import instance_lookup, remap_instances
from carlaocc.catalog.formats.manifest import grid_manifest, save_grid_manifest
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.pipeline.commands.export.spec import (ExportFormat, ExportJob, actor_ids, save_sequence_splits,
                                                    sequence_release_ids, voxelized_export)
from carlaocc.schemas import taxonomy


def write_npz(job: ExportJob) -> tuple[int, int, int]:
    """Every frame of every voxelized sequence on our own grid, labels in ``job.options["encoding"]``."""
    store, out, encoding = job.store, job.out, job.options["encoding"]
    todo, splits, label_table = voxelized_export(job)
    occ = OccupancyStore(store)
    n_frames = n_files = 0
    for seq, grid, frame_count in todo:
        # the published id layout, stable across the sequence (a first pass collects the ids
        # frame by frame: one dense frame in memory at a time)
        table = sequence_release_ids(occ, seq, grid, frame_count, actor_ids(store, seq), encoding)
        keys, vals = instance_lookup(table)
        atomic_write(out / seq / "instances.json", lambda fh: fh.write(json.dumps(
            {"encoding": encoding, "instances": {f"{c}:{i}": v for (c, i), v in sorted(table.items())}},
            indent=1).encode()))
        for t in range(frame_count):
            data = occ.read_frame(seq, grid, t, ("semantic", "instance"))
            compact = remap_instances(data["semantic"], data["instance"], keys, vals)
            save_carlaocc_npz(out / seq / f"{t:06d}.npz", data["semantic"], compact, grid.voxel_size, grid.origin,
                              encoding)
            n_files += 1
            n_frames += 1
            job.advance()
    g = todo[0][1]
    labels = [c.name for c in taxonomy.label_table(label_table).classes]
    manifest = grid_manifest("carlaocc-npz", "lidar", [{"origin": g.origin, "voxel_size": g.voxel_size, "shape": g.shape}],
                             labels, 0, label_table, encoding=encoding)
    n_files += save_grid_manifest(out, manifest)
    n_files += save_sequence_splits(out, [s for s, _, _ in todo], splits)
    return len(todo), n_frames, n_files


FORMATS = (
    ExportFormat("carlaocc-npz", "<seq>/<frame>.npz on our grid; labels semantic << 11 | instance as the release's "
                 "code reads them, or --label-encoding decimal; ids renumbered per class where they would collide",
                 write_npz, options={"encoding": LABEL_ENCODINGS}),
)
