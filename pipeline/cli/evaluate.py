"""``carlaocc eval ssc|panoptic|depth|det``: score a model's predictions against ground truth.

Reads prediction and ground-truth files, feeds them frame by frame to the accumulators of
:mod:`carlaocc.stages.evaluation`, prints a table and optionally writes the full result as JSON.

Inputs (``--pred`` and ``--gt`` are both files, or both directories):

* Directories are paired by relative path **without the suffix** (``pred/seq/000.npy`` scores
  against ``gt/seq/000.npz``); a ground-truth file without a prediction, a prediction without
  ground truth, or two candidates for one key is an error naming the file (exit code 2).
* ``ssc`` / ``panoptic``: ``.npz`` with an array ``semantics`` (and ``instances`` for panoptic)
  of one shape, labels in the ``--map`` space; a ground-truth npz may add ``mask_camera`` /
  ``mask_lidar`` (0/1), so an Occ3D ``labels.npz`` is ground truth as it is. A prediction may also
  be an ``.npy`` or a one-array ``.npz`` holding the semantics. A published CarlaOcc ``.npz``
  (``occupancy`` rows, ``semantic << 11 | instance``, or decimal when the file says so) is read on either side and its CarlaOcc ids are
  mapped into ``--map`` through the taxonomy.
* ``depth``: ``.npy`` or ``.npz`` (array ``depth``, or a single array), float metres, ``(H, W)``;
  ground truth 0 (or outside the cap) is invalid.
* ``det``: JSON. A file holds ``{sample_id: [box, ...], ...}`` (optionally wrapped as
  ``{"results": {...}}``, the nuScenes submission layout); in a directory each file is one sample,
  a list of boxes, its id the relative path. A box is
  ``{"center": [x, y, z], "size": [l, w, h], "yaw": rad, "label": "Car", "score": 0.9}`` or the
  nuScenes form ``{"translation", "size": [w, l, h], "rotation": [qw, qx, qy, qz],
  "detection_name", "detection_score"}``. Ground truth needs no score. Both files must list the
  same samples.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
import typer

from carlaocc.catalog.formats.predictions import InputError, load_arrays, load_occupancy, pair_files
from carlaocc.pipeline.cli.common import CommandGroup

__all__ = ["eval_app"]

eval_app = typer.Typer(
    cls=CommandGroup,
    help="Score a model trained on the data: semantic occupancy (IoU, mIoU), panoptic occupancy "
    "(PQ, SQ, RQ), monocular depth (AbsRel ... delta) and 3D detection (nuScenes mAP, mATE, mASE, "
    "mAOE). Prints a table; --json writes everything.",
    no_args_is_help=True,
    rich_markup_mode=None,
)

PredOpt = Annotated[Path, typer.Option("--pred", help="prediction file or directory")]
GtOpt = Annotated[Path, typer.Option("--gt", help="ground-truth file or directory (paired with --pred by relative path)")]
MapOpt = Annotated[str, typer.Option("--map", help="label space: carlaocc (30, 0 = free) | benchmark (paper's 15 + 15 = free) | occ3d (18, 17 = free) | sscbench (19, 0 = empty) | semantickitti (20, 0 = empty)")]
IgnoreOpt = Annotated[str, typer.Option("--ignore", help="comma-separated label ids to skip (ground truth: void; prediction: abstain)")]
MaskOpt = Annotated[str, typer.Option("--mask", help="none | camera | lidar: score only voxels the ground truth's mask_camera / mask_lidar marks")]
TaxonomyOpt = Annotated[str, typer.Option("--taxonomy", help="label table of the CarlaOcc ids: release (the official release's utils/labels.py, the default) | carlaocc-v1; decides the thing classes and the Occ3D / KITTI-360 ids")]
JsonOpt = Annotated[Optional[Path], typer.Option("--json", help="write the full result (per class, means, confusion) as JSON here")]


def _fail(message: str) -> None:
    from carlaocc.pipeline.cli.common import fail

    fail(message, 2)


def _pick_mask(mask: str, masks: dict[str, np.ndarray], shape, path: Path) -> np.ndarray | None:
    if mask == "none":
        return None
    key = f"mask_{mask}"
    if key not in masks:
        raise InputError(f"{path}: --mask {mask} needs a '{key}' array in the ground truth")
    m = masks[key]
    if m.shape != shape:
        raise InputError(f"{path}: {key} {m.shape} and semantics {shape} differ in shape")
    return m.astype(bool)


def _ids(text: str, opt: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise InputError(f"{opt} {text!r}: expected comma-separated integer label ids") from None


def _label_map(name: str, table: str):
    from carlaocc.schemas.taxonomy import label_table
    from carlaocc.stages.evaluation import label_map

    try:
        label_table(table)
    except ValueError as exc:
        raise InputError(f"--taxonomy: {exc}") from None
    try:
        return label_map(name, table)
    except ValueError as exc:
        raise InputError(f"--map: {exc}") from None


# --------------------------------------------------------------------------- output


def percent(v: float | None) -> str:
    return "     -" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:6.2f}"


def write_json(out: Path | None, data: dict[str, Any]) -> None:
    if out is None:
        return
    from carlaocc.catalog.formats import atomic_write

    try:
        atomic_write(out, lambda fh: fh.write((json.dumps(data, indent=1, allow_nan=False) + "\n").encode()))
    except OSError as exc:
        raise InputError(f"--json {out}: cannot write: {exc.strerror or exc}") from exc


def run_checked(fn) -> None:
    """Run ``fn``; bad input becomes a one-line error with exit code 2."""
    try:
        fn()
    except InputError as exc:
        _fail(str(exc))
    except FileNotFoundError as exc:
        _fail(f"{exc.filename}: no such file")


def _frame_error(key: str, exc: ValueError) -> InputError:
    return InputError(f"{key}: {exc}")


def _occupancy_pairs(pred: Path, gt: Path, lm, mask: str, instances: bool, suffixes: tuple[str, ...]):
    """Paired prediction / ground-truth grids, loaded and checked: yields (prediction file,
    (pred semantics, pred instances), (gt semantics, gt instances), the --mask array or None)."""
    for _, pf, gf in pair_files(pred, gt, suffixes):
        p_sem, p_inst, _ = load_occupancy(pf, lm, instances)
        g_sem, g_inst, masks = load_occupancy(gf, lm, instances)
        if p_sem.shape != g_sem.shape:
            raise InputError(f"{pf}: shape {p_sem.shape} differs from ground truth {gf} {g_sem.shape}")
        yield pf, (p_sem, p_inst), (g_sem, g_inst), _pick_mask(mask, masks, g_sem.shape, gf)


# --------------------------------------------------------------------------- commands


@eval_app.command("ssc")
def ssc_cmd(pred: PredOpt, gt: GtOpt, map_name: MapOpt = "carlaocc", ignore: IgnoreOpt = "255",
            mask: MaskOpt = "none", table: TaxonomyOpt = "release", json_out: JsonOpt = None) -> None:  # fmt: skip
    """Semantic occupancy: per-class IoU, mIoU (classes absent from both sides are left out) and
    geometry IoU / precision / recall (occupied vs free), summed over all frames.

    Inputs: two .npz files, or two directories paired by relative path without suffix. An npz
    holds an integer array 'semantics' with labels in --map (a prediction may also be an .npy or a
    one-array npz); ground truth may add 0/1 'mask_camera' / 'mask_lidar', so an Occ3D
    labels.npz is ground truth as it is. A CarlaOcc npz ('occupancy' rows, semantic << 11 | instance; decimal when its label_encoding key says so) is
    read on either side, its CarlaOcc ids mapped into --map. Missing counterpart: exit code 2."""

    def go() -> None:
        from carlaocc.stages.evaluation import SSCAccumulator

        lm = _label_map(map_name, table)
        if mask not in ("none", "camera", "lidar"):
            raise InputError(f"--mask must be none, camera or lidar, got {mask!r}")
        acc = SSCAccumulator(lm, _ids(ignore, "--ignore"))
        for pf, (p_sem, _), (g_sem, _), m in _occupancy_pairs(pred, gt, lm, mask, False, (".npz", ".npy")):
            try:
                acc.update(p_sem, g_sem, m)
            except ValueError as exc:
                raise _frame_error(str(pf), exc) from exc
        res = acc.result()
        data = res.to_dict() | {"pred": str(pred), "gt": str(gt), "ignore": list(acc.ignore), "mask": mask}
        write_json(json_out, data)
        typer.echo(f"{'class':<22} {'IoU %':>6} {'gt voxels':>12}")
        for row in data["classes"]:
            typer.echo(f"{row['name']:<22} {percent(row['iou'])} {row['tp'] + row['fn']:>12,}")
        typer.echo(f"{'mIoU':<22} {percent(data['miou'])}")
        g = data["geometry"]
        typer.echo(f"{'geometry IoU':<22} {percent(g['iou'])}   precision {percent(g['precision'])}   recall {percent(g['recall'])}")
        typer.echo(f"{res.frames} frame(s), {res.voxels:,} voxels scored, map {lm.name}")

    run_checked(go)


@eval_app.command("panoptic")
def panoptic_cmd(
    pred: PredOpt, gt: GtOpt, map_name: MapOpt = "carlaocc", ignore: IgnoreOpt = "255", mask: MaskOpt = "none",
    table: TaxonomyOpt = "release",
    min_size: Annotated[int, typer.Option("--min-size", min=0, help="voxels: unmatched segments smaller than this are neither FN nor FP")] = 0,
    things: Annotated[Optional[str], typer.Option("--things", help="comma-separated thing label ids (default: the map's, from the taxonomy)")] = None,
    json_out: JsonOpt = None,
) -> None:  # fmt: skip
    """Panoptic occupancy: PQ, SQ, RQ per class and over all / thing / stuff classes (IoU > 0.5
    matching; void = ground truth in --ignore; a prediction mostly on void is not an FP; stuff
    segment = a class's voxels in a frame, thing segment = (class, instance)).

    Inputs: as for `eval ssc` (.npz only), plus an integer array 'instances' of the same shape
    on both sides; a CarlaOcc npz carries both."""

    def go() -> None:
        from carlaocc.stages.evaluation import PanopticAccumulator

        lm = _label_map(map_name, table)
        if mask not in ("none", "camera", "lidar"):
            raise InputError(f"--mask must be none, camera or lidar, got {mask!r}")
        try:
            acc = PanopticAccumulator(lm, _ids(ignore, "--ignore"), min_size,
                                      None if things is None else _ids(things, "--things"))  # fmt: skip
        except ValueError as exc:
            raise InputError(f"--things: {exc}") from None
        for pf, (p_sem, p_inst), (g_sem, g_inst), m in _occupancy_pairs(pred, gt, lm, mask, True, (".npz",)):
            try:
                acc.update(p_sem, p_inst, g_sem, g_inst, m)
            except ValueError as exc:
                raise _frame_error(str(pf), exc) from exc
        res = acc.result()
        data = res.to_dict() | {"pred": str(pred), "gt": str(gt), "ignore": list(acc.ignore), "mask": mask}
        write_json(json_out, data)
        typer.echo(f"{'class':<22} {'kind':<6} {'PQ %':>6} {'SQ %':>6} {'RQ %':>6} {'TP':>7} {'FP':>7} {'FN':>7}")
        for r in data["classes"]:
            typer.echo(f"{r['name']:<22} {'thing' if r['thing'] else 'stuff':<6} {percent(r['pq'])} {percent(r['sq'])} "
                       f"{percent(r['rq'])} {r['tp']:>7} {r['fp']:>7} {r['fn']:>7}")
        for suffix, name in (("", "all"), ("_things", "things"), ("_stuff", "stuff")):
            typer.echo(f"{'mean ' + name:<29} {percent(data['pq' + suffix])} {percent(data['sq' + suffix])} {percent(data['rq' + suffix])}")
        typer.echo(f"{res.frames} frame(s), map {lm.name}, min segment size {min_size} voxels")

    run_checked(go)


def _load_depth(path: Path) -> np.ndarray:
    arrays = load_arrays(path)
    if "depth" in arrays:
        d = arrays["depth"]
    elif len(arrays) == 1:
        d = next(iter(arrays.values()))
    else:
        raise InputError(f"{path}: no 'depth' array (found {sorted(arrays)})")
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.number):
        raise InputError(f"{path}: depth must be a 2-D (H, W) numeric array in metres, got {d.shape} {d.dtype}")
    return d


@eval_app.command("depth")
def depth_cmd(
    pred: PredOpt, gt: GtOpt,
    min_depth: Annotated[float, typer.Option("--min-depth", help="metres: ground truth at or below is invalid; predictions are clipped up to it")] = 1e-3,
    max_depth: Annotated[float, typer.Option("--max-depth", help="metres: ground truth at or beyond is invalid; predictions are clipped down to it")] = 80.0,
    scale: Annotated[str, typer.Option("--scale", help="none | median: per-image median scaling for relative-depth models")] = "none",
    json_out: JsonOpt = None,
) -> None:  # fmt: skip
    """Monocular depth: AbsRel, SqRel, RMSE, RMSElog, delta < 1.25^k over valid pixels
    (min < gt < max), pooled over all pixels and as the mean of per-image values.

    Inputs: two files or two directories paired by relative path without suffix; each an .npy,
    or an .npz with an array 'depth' (or a single array): (H, W) float metres, ground truth 0 =
    no depth."""

    def go() -> None:
        from carlaocc.stages.evaluation import DepthAccumulator

        try:
            acc = DepthAccumulator(min_depth, max_depth, scale)  # type: ignore[arg-type]
        except ValueError as exc:
            raise InputError(str(exc)) from None
        for key, pf, gf in pair_files(pred, gt, (".npy", ".npz")):
            p, g = _load_depth(pf), _load_depth(gf)
            if p.shape != g.shape:
                raise InputError(f"{pf}: shape {p.shape} differs from ground truth {gf} {g.shape}")
            try:
                acc.update(p, g)
            except ValueError as exc:
                raise _frame_error(str(pf), exc) from exc
        res = acc.result()
        data = res.to_dict() | {"pred": str(pred), "gt": str(gt)}
        write_json(json_out, finite_json(data))
        names = ("AbsRel", "SqRel", "RMSE", "RMSElog", "d<1.25", "d<1.25^2", "d<1.25^3")
        typer.echo(f"{'average':<8} " + " ".join(f"{n:>9}" for n in names))
        for avg in ("pixel", "image"):
            vals = [data[avg][k] for k in data[avg]]
            typer.echo(f"{avg:<8} " + " ".join("        -" if v is None else f"{v:9.4f}" for v in vals))
        typer.echo(f"{res.images} image(s) ({res.valid_images} with valid pixels), {res.pixels:,} valid pixels, "
                   f"cap ({min_depth:g}, {max_depth:g}) m, scale {scale}")

    run_checked(go)


def _box(obj: Any, where: str, need_score: bool):
    from carlaocc.stages.evaluation import Box3D

    if not isinstance(obj, dict):
        raise InputError(f"{where}: a box must be a JSON object, got {type(obj).__name__}")
    try:
        if "center" in obj:
            center, size, yaw, label = obj["center"], obj["size"], obj["yaw"], obj["label"]
            score = obj.get("score")
        else:  # nuScenes: size is (w, l, h), rotation a (w, x, y, z) quaternion
            center, (w, l, h), label = obj["translation"], obj["size"], obj["detection_name"]
            size = (l, w, h)
            qw, qx, qy, qz = (float(v) for v in obj["rotation"])
            # the yaw of the normalised quaternion (the devkit normalises through pyquaternion)
            norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            if not (math.isfinite(norm) and norm > 0):
                raise InputError(f"{where}: rotation {obj['rotation']} is not a rotation quaternion")
            qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
            yaw = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
            score = obj.get("detection_score")
        if need_score and score is None:
            raise InputError(f"{where}: a predicted box needs a score")
        vel = obj.get("velocity")
        vel = None if vel is None or not all(v is not None and math.isfinite(float(v)) for v in vel[:2]) else \
            (float(vel[0]), float(vel[1]))
        ego = obj.get("ego_translation")
        ego_dist = math.hypot(float(ego[0]), float(ego[1])) if ego is not None else obj.get("ego_dist")
        ego_xy = None if ego is None else (float(center[0]) - float(ego[0]), float(center[1]) - float(ego[1]))
        return Box3D(tuple(float(v) for v in center), tuple(float(v) for v in size), float(yaw), str(label),
                     1.0 if score is None else float(score), vel, str(obj.get("attribute_name", obj.get("attribute", "")) or ""),
                     int(obj.get("num_lidar_pts", obj.get("num_pts", -1))),
                     None if ego_dist is None else float(ego_dist), ego_xy)  # fmt: skip
    except KeyError as exc:
        raise InputError(f"{where}: box lacks {exc}; expected center/size/yaw/label[/score] or "
                         f"translation/size/rotation/detection_name[/detection_score]") from None
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{where}: bad box: {exc}") from None


def load_boxes(path: Path, need_score: bool, sample: str | None = None) -> dict[str, list]:
    """``{sample: [Box3D]}`` from a JSON file; with ``sample``, the file is that one sample's list."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not readable JSON ({exc})") from exc
    if sample is not None:
        if isinstance(data, dict) and "boxes" in data:
            data = data["boxes"]
        data = {sample: data}
    elif isinstance(data, dict) and isinstance(data.get("results"), dict):
        data = data["results"]
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected an object mapping sample ids to box lists")
    out: dict[str, list] = {}
    for s, boxes in data.items():
        if not isinstance(boxes, list):
            raise InputError(f"{path}: sample {s!r}: expected a list of boxes")
        out[str(s)] = [_box(b, f"{path}: sample {s!r} box {i}", need_score) for i, b in enumerate(boxes)]
    return out


def _with_ego_distance(p_all: dict, g_all: dict, gt: Path) -> dict:
    """Predictions with their distance from the ego (the devkit recomputes it from the ego pose
    for both sides): the ego's position per sample from the ground truth's ``ego_translation``
    (or its ``meta.ego_positions``, ``export det-gt``); a prediction already carrying
    ``ego_translation`` keeps its own."""
    import dataclasses

    egos: dict[str, tuple[float, float]] = {}
    if gt.is_file():
        try:
            meta = json.loads(gt.read_text()).get("meta", {}) or {}
        except (OSError, json.JSONDecodeError, AttributeError):
            meta = {}
        for tok, pos in (meta.get("ego_positions") or {}).items():
            egos[str(tok)] = (float(pos[0]), float(pos[1]))
    for s, boxes in g_all.items():
        for b in boxes:
            if s not in egos and b.ego_xy is not None:
                egos[s] = b.ego_xy
    out = {}
    for s, boxes in p_all.items():
        fixed = []
        for b in boxes:
            if b.ego_dist is None:
                if s not in egos:
                    raise InputError(f"--nuscenes-filters: sample {s!r} has no ego position (the ground truth's "
                                     "ego_translation or meta.ego_positions) to measure the predictions' range from")
                b = dataclasses.replace(b, ego_dist=math.hypot(b.center[0] - egos[s][0], b.center[1] - egos[s][1]))
            fixed.append(b)
        out[s] = fixed
    return out


@eval_app.command("det")
def det_cmd(
    pred: PredOpt, gt: GtOpt,
    classes: Annotated[Optional[str], typer.Option("--classes", help="comma-separated class names to score (default: those in the ground truth)")] = None,
    nuscenes_filters: Annotated[bool, typer.Option("--nuscenes-filters", help="the devkit's filters: nuScenes classes beyond their range of the ego (ego_translation of a box, else its centre's distance from the origin) and ground-truth boxes with num_lidar_pts 0 are dropped")] = False,
    json_out: JsonOpt = None,
) -> None:  # fmt: skip
    """3D detection, nuScenes protocol: AP at BEV centre distances 0.5/1/2/4 m (101-point,
    min recall/precision 0.1), mATE / mASE / mAOE / mAVE / mAAE at 2 m and NDS (velocity and
    attribute_name from the boxes where given; the devkit's cone and barrier rules).

    Inputs: two JSON files {sample_id: [box, ...]} (or nuScenes' {"results": {...}}), both
    listing the same samples; or two directories of one JSON box list per sample, paired by
    relative path. A box: {"center": [x, y, z], "size": [l, w, h], "yaw": rad, "label": name,
    "score": s} or nuScenes' {"translation", "size": [w, l, h], "rotation": [qw, qx, qy, qz],
    "detection_name", "detection_score"}; ground-truth boxes need no score."""

    def go() -> None:
        from carlaocc.stages.evaluation import DetectionAccumulator

        if pred.is_file() and gt.is_file():
            p_all, g_all = load_boxes(pred, True), load_boxes(gt, False)
            for s in g_all:
                if s not in p_all:
                    raise InputError(f"{pred}: no entry for sample {s!r} of {gt} (use [] for no detections)")
            for s in p_all:
                if s not in g_all:
                    raise InputError(f"{pred}: sample {s!r} is not in the ground truth {gt}")
        else:
            p_all, g_all = {}, {}
            for key, pf, gf in pair_files(pred, gt, (".json",)):
                p_all |= load_boxes(pf, True, key)
                g_all |= load_boxes(gf, False, key)
        cls = None if classes is None else tuple(c.strip() for c in classes.split(",") if c.strip())
        if nuscenes_filters:
            p_all = _with_ego_distance(p_all, g_all, gt)
        acc = DetectionAccumulator(classes=cls or None, nuscenes_filters=nuscenes_filters)
        if not cls and not any(g_all.values()):
            raise InputError(f"--gt {gt} holds no boxes: nothing to score (name --classes to score false positives)")
        for s in g_all:
            acc.update(s, p_all[s], g_all[s])
        res = acc.result()
        data = res.to_dict() | {"pred": str(pred), "gt": str(gt)}
        write_json(json_out, finite_json(data))
        f3 = lambda v: "     -" if v is None or not math.isfinite(v) else f"{v:6.3f}"  # noqa: E731
        typer.echo(f"{'class':<18} {'AP':>6} {'ATE m':>7} {'ASE':>6} {'AOE rad':>8} {'AVE m/s':>8} {'AAE':>6} {'gt':>7} {'pred':>7}")
        for r in data["classes"]:
            typer.echo(f"{r['name']:<18} {r['ap']:6.3f} {r['ate']:7.3f} {r['ase']:6.3f} {f3(r['aoe']):>8} {f3(r['ave']):>8} "
                       f"{f3(r['aae']):>6} {r['gt']:>7} {r['pred']:>7}")
        typer.echo(f"{'mean':<18} {res.mean_ap:6.3f} {res.mate:7.3f} {res.mase:6.3f} {f3(res.maoe):>8} {f3(res.mave):>8} {f3(res.maae):>6}")
        typer.echo(f"{res.samples} sample(s); mAP {res.mean_ap:.4f}, mATE {res.mate:.4f}, mASE {res.mase:.4f}, mAOE {res.maoe:.4f}, "
                   f"mAVE {res.mave:.4f}, mAAE {res.maae:.4f}, NDS {res.nds:.4f}")

    run_checked(go)


def finite_json(obj):
    """NaN -> None throughout (strict JSON)."""
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
