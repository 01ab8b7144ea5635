"""``carlaocc audit FORMAT PATH... [--poses FILE] [--calib FILE]``: the paper's quality scores
(section 4.2, Table 4) of other occupancy datasets.

The wiring: the format's layout (:data:`carlaocc.catalog.formats.FORMATS`, its table of files, grids,
label conventions and sequences in :mod:`carlaocc.catalog.formats.layout`) collects the files under each
PATH and groups them into sequences; :mod:`carlaocc.catalog.formats.poses` reads ``--poses`` (keyed by frame
or one per listed frame; with ``--calib``, KITTI camera-0 poses are turned into LiDAR poses
``inv(Tr) @ P @ Tr``) and gives each frame its pose; :func:`audit` then reads the frames one at a
time and scores them with :mod:`carlaocc.stages.quality`: ``s_sc`` per frame and over all frames (the
labels as published), ``s_tc`` per pair of consecutive posed frames **within** one sequence (its
counts summed over the sequences), the format's dynamic classes excluded, its visibility mask
applied where both frames have one. :func:`format_table` prints the paper's columns; ``--json``
writes the per-frame, per-pair and per-class counts.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from carlaocc.catalog.formats import DatasetFormat, DatasetInputError, atomic_write, dataset_format
from carlaocc.catalog.formats.layout import LabelGrid, collect_inputs, read_frame
from carlaocc.catalog.formats.poses import KeyedPoses, PosedSequence, load_kitti_calib, load_poses, plan_sequences
from carlaocc.stages.quality import (column_ranges, sequence_continuity, sequence_temporal, spatial_continuity_counts,
                                     static_table, temporal_consistency_counts)

if TYPE_CHECKING:
    from carlaocc.stages.quality import ContinuityCounts, TemporalCounts


@dataclass
class AuditResult:
    """Scores of one audited set of frames; counts indexed by internal id."""

    fmt: DatasetFormat
    frames: list[dict] = field(default_factory=list)  # path, sequence, s_sc, occupied, isolated, pose
    pairs: list[dict] = field(default_factory=list)  # t, t1 (frame indices), sequence, s_tc, intersection, union
    sequences: int = 0
    without_pose: int = 0  # frames left out of s_tc for want of a pose (keyed poses)
    poses_unmatched: int = 0  # keyed pose entries naming no audited file
    continuity: ContinuityCounts | None = None
    temporal: TemporalCounts | None = None  # None without poses

    @property
    def s_sc(self) -> float:
        return self.continuity.score

    @property
    def s_tc(self) -> float | None:
        return None if self.temporal is None else self.temporal.score

    def per_class(self) -> list[dict]:
        """One row per class present: dataset id, name and its counts."""
        rows = []
        for i in range(1, 256):
            occ, iso = int(self.continuity.occupied[i]), int(self.continuity.isolated[i])
            inter = int(self.temporal.intersection[i]) if self.temporal is not None else 0
            union = int(self.temporal.union[i]) if self.temporal is not None else 0
            if occ or union:
                did = self.fmt.to_dataset_id(i)
                name = self.fmt.class_names[did] if 0 <= did < len(self.fmt.class_names) else f"id {did}"
                row = {"id": did, "name": name, "occupied": occ, "isolated": iso,
                       "s_sc": _nan_to_none(1 - iso / occ if occ else float("nan"))}
                if self.temporal is not None:
                    row |= {"intersection": inter, "union": union,
                            "iou": _nan_to_none(inter / union if union else float("nan"))}
                rows.append(row)
        return rows

    def to_json(self) -> dict:
        c, t = self.continuity, self.temporal
        return {
            "format": self.fmt.name,
            "dataset": self.fmt.dataset,
            "frames": len(self.frames),
            "sequences": self.sequences,
            "pairs": len(self.pairs),
            "frames_without_pose": None if t is None else self.without_pose,
            "poses_unmatched": None if t is None else self.poses_unmatched,
            "s_sc": _nan_to_none(self.s_sc),
            "occupied": int(c.occupied[1:].sum()),
            "isolated": int(c.isolated[1:].sum()),
            "s_tc": None if t is None else _nan_to_none(t.score),
            "s_tc_class_mean": None if t is None else _nan_to_none(t.mean_class_iou()),
            "intersection": None if t is None else t.total_intersection,
            "union": None if t is None else t.total_union,
            "visibility_mask": self.fmt.mask,
            "per_frame": self.frames,
            "per_pair": self.pairs,
            "per_class": self.per_class(),
        }


def _nan_to_none(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def audit(fmt: DatasetFormat, sequences: Sequence[PosedSequence]) -> AuditResult:
    """s_sc per frame and over all frames; where the sequences carry poses, s_tc per pair of
    consecutive frames with a pose **within** one sequence, and over all pairs (counts summed over
    the sequences). Frames are read and scored one at a time (two in memory)."""

    static = static_table(fmt.dynamic)
    has_poses = any(s.poses is not None for s in sequences)
    result = AuditResult(fmt, sequences=len(sequences))
    counts, pair_counts = [], []
    for seq in sequences:
        poses = seq.poses if seq.poses is not None else (None,) * len(seq.files)
        if len(poses) != len(seq.files):
            raise DatasetInputError(f"{seq.name}: {len(poses)} poses for {len(seq.files)} frames")
        prev: tuple[int, LabelGrid, np.ndarray, tuple] | None = None  # the last frame with a pose
        for path, pose in zip(seq.files, poses):
            frame = read_frame(fmt, path)
            t = len(result.frames)
            c = spatial_continuity_counts(frame.semantic)
            counts.append(c)
            result.frames.append({"path": frame.path, "sequence": seq.name, "s_sc": _nan_to_none(c.score),
                                  "occupied": int(c.occupied[1:].sum()), "isolated": int(c.isolated[1:].sum()),
                                  "pose": pose is not None})
            if pose is None:
                result.without_pose += has_poses
                continue
            ranges = column_ranges(frame.semantic)  # serves both pairs of the frame
            if prev is not None:
                t0, f0, p0, ranges0 = prev
                use_mask = f0.mask is not None and frame.mask is not None
                tc = temporal_consistency_counts(
                    f0.semantic, frame.semantic, p0, pose, f0.voxel_size, f0.origin,
                    mask_t=f0.mask if use_mask else None, mask_t1=frame.mask if use_mask else None,
                    static=static, voxel_size_t1=frame.voxel_size, origin_t1=frame.origin,
                    ranges_t=ranges0, ranges_t1=ranges)
                pair_counts.append(tc)
                result.pairs.append({"t": t0, "t1": t, "sequence": seq.name, "s_tc": _nan_to_none(tc.score),
                                     "intersection": tc.total_intersection, "union": tc.total_union})
            prev = (t, frame, pose, ranges)
    result.continuity = sequence_continuity(counts)
    if has_poses:
        result.temporal = sequence_temporal(pair_counts)
    return result


def _fmt(v: float | None, digits: int = 4) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def format_table(result: AuditResult, per_frame: bool = False) -> str:
    """The paper's Table 4 columns (dataset, frames, s_sc, s_tc) plus the voxel counts, and a line
    saying what s_tc was computed over."""
    c = result.continuity
    lines = []
    if per_frame:
        lines.append(f"{'frame':>6}  {'s_sc':>7}  {'occupied':>12}  {'isolated':>10}  {'s_tc (t, next)':>14}  path")
        tc = {p["t"]: p["s_tc"] for p in result.pairs}
        for t, f in enumerate(result.frames):
            lines.append(f"{t:>6}  {_fmt(f['s_sc']):>7}  {f['occupied']:>12,}  {f['isolated']:>10,}  "
                         f"{_fmt(tc.get(t)):>14}  {f['path']}")
        lines.append("")
    lines.append(f"{'dataset':<16} {'frames':>7} {'s_sc':>7} {'s_tc':>7} {'occupied':>14} {'isolated':>12}")
    lines.append(f"{result.fmt.dataset:<16} {len(result.frames):>7} {_fmt(result.s_sc):>7} {_fmt(result.s_tc):>7} "
                 f"{int(c.occupied[1:].sum()):>14,} {int(c.isolated[1:].sum()):>12,}")
    if result.temporal is not None:
        note = f"s_tc over {len(result.pairs)} pairs of consecutive frames within {result.sequences} sequence(s)"
        if result.without_pose:
            note += f"; {result.without_pose} frame(s) without a pose left out"
        if result.poses_unmatched:
            note += f"; {result.poses_unmatched} pose(s) naming no audited file ignored"
        lines.append(note)
    return "\n".join(lines)


def audit_command(
    fmt: str,
    paths: list[str],
    poses: str | None = None,
    calib: str | None = None,
    json_out: str | None = None,
    per_frame: bool = False,
) -> tuple[AuditResult, str]:
    """The CLI's work: (result, printed table). Raises :class:`DatasetInputError` on bad input."""
    spec = dataset_format(fmt)
    inputs = collect_inputs(spec, paths)
    pose_spec = load_poses(poses) if poses is not None else None
    if calib is not None:
        if pose_spec is None:
            raise DatasetInputError("--calib converts --poses from camera 0 to the LiDAR: give --poses too")
        tr = load_kitti_calib(calib)
        if isinstance(pose_spec, KeyedPoses):
            pose_spec = KeyedPoses(pose_spec.frames, np.linalg.inv(tr) @ pose_spec.poses @ tr)
        else:
            pose_spec = np.linalg.inv(tr) @ pose_spec @ tr
    sequences, unmatched = plan_sequences(spec, inputs, pose_spec, str(poses))
    result = audit(spec, sequences)
    result.poses_unmatched = unmatched
    if json_out is not None:
        out = Path(json_out)
        try:
            atomic_write(out, lambda fh: fh.write(json.dumps(result.to_json(), indent=1).encode()))
        except OSError as exc:
            raise DatasetInputError(f"cannot write {out}: {exc.strerror or exc}") from None
    return result, format_table(result, per_frame)
