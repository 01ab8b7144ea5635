"""``carlaocc eval rayiou|raypq``: SparseOcc's ray metrics (and OccNet's flow score) on
Occ3D-layout trees or carlaocc roots -- the inputs, the ray origins from info pickles or a root's
poses, and the table; the compute is :mod:`carlaocc.stages.evaluation.rays`."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from carlaocc.pipeline.cli.evaluate import (InputError, JsonOpt, eval_app, finite_json, load_arrays, percent,
                                           run_checked, write_json)
from carlaocc.schemas import taxonomy

__all__ = ["origins_from_poses", "ray_origins", "ray_pairs"]

# -- ray-based metrics (SparseOcc's RayIoU / RayPQ) --------------------------------------------------

RAY_CLASSES = {"occ3d": "occ3d_nuscenes", "openocc-v2": "openocc_v2"}
# nuScenes' LIDAR_TOP lidar2ego translation (m, ego frame): the calibrated_sensor record SparseOcc's
# loaders/ray_metrics.py comments as (0.9858, 0.0000, 1.8402) (one of the trainval calibrations,
# z 1.84019 / 1.84023 / 1.84292: nuscenes-devkit issue #161). Without --infos, SparseOcc's
# protocol for a sample alone in its scene casts from there (ego_pose_dataset: the sample's own
# LiDAR origin mapped into its ego frame is its lidar2ego translation). Occ3D-nuScenes and
# OpenOcc v2 are both nuScenes grids.
LIDAR2EGO = {"occ3d": (0.985793, 0.0, 1.84019), "openocc-v2": (0.985793, 0.0, 1.84019)}
# road users with one RayPQ segment per instance (SparseOcc's thing list), by class name
RAY_THINGS = ("car", "truck", "construction_vehicle", "bus", "trailer", "motorcycle", "bicycle", "pedestrian")


def _is_root(path: Path) -> bool:
    """A built carlaocc root (not an Occ3D tree)."""
    return (path / "scenes" / "sequences").is_dir()


def _root_index(path: Path, opt: str):
    """``(dataset, {token: sample index})`` of a built root, tokens ``<sequence>_<frame:06d>``."""
    from carlaocc.catalog.samples import DatasetError, FrameSamples
    try:
        ds = FrameSamples(str(path), occupancy="none", cameras=False, lidar=False, boxes=False)
    except DatasetError as exc:
        raise InputError(f"{opt} {path}: {exc}") from None
    return ds, {f"{s}_{f:06d}": k for k, (s, f) in enumerate(ds.samples)}


def _prediction(pred: Path, scene: str, token: str, where: str, index=None):
    """A sample's prediction: a file of an Occ3D tree (or SparseOcc's flat ``<token>.npz``), or
    ``(dataset, k)`` of a prediction root (``index`` from :func:`_root_index`)."""
    if index is not None:
        ds, tokens = index
        if token not in tokens:
            raise InputError(f"no prediction for {where}: --pred root {pred} has no {token}")
        return ds, tokens[token]
    cands = [pred / scene / token / "labels.npz", pred / f"{token}.npz"]
    p = next((c for c in cands if c.is_file()), None)
    if p is None:
        raise InputError(f"no prediction for {where} (expected {cands[0]} or {cands[1]})")
    return p


def ray_pairs(pred: Path, gt: Path) -> list[tuple[str, str, object, Path]]:
    """``(scene, token, prediction, gt_file)`` of an Occ3D-layout ground-truth tree
    (``<scene>/<token>/labels.npz``) and a prediction tree in the same layout, SparseOcc's flat
    ``<token>.npz``, or a carlaocc root; errors name what is missing."""
    for opt, p in (("--pred", pred), ("--gt", gt)):
        if not p.is_dir():
            raise InputError(f"{opt} {p} is not a directory (an Occ3D-layout tree <scene>/<token>/labels.npz)")
    gts = sorted(gt.glob("*/*/labels.npz"))
    if not gts:
        raise InputError(f"--gt {gt} holds no <scene>/<token>/labels.npz")
    index = _root_index(pred, "--pred") if _is_root(pred) else None
    return [(g.parent.parent.name, g.parent.name, _prediction(pred, g.parent.parent.name, g.parent.name, str(g), index), g)
            for g in gts]


def ray_origins(infos_files: list[Path]) -> dict[str, np.ndarray]:
    """``token -> (T, 3)`` ray origins (ego frame, m) from info pickles (ours or BEVDet's: per
    info ``token``, ``scene_name``, ``timestamp``, ``lidar2ego_*`` and ``ego2global_*``
    translation + quaternion w x y z): the LiDAR positions of the scene's frames in the sample's
    ego frame (SparseOcc's ego_pose_dataset), then :func:`select_origins`."""
    from carlaocc.stages.geometry import rotation_from_quaternion
    def pose(t, q) -> np.ndarray:
        try:
            t, q = np.asarray(t, float).reshape(3), np.asarray(q, float).reshape(4)
        except (TypeError, ValueError):
            raise InputError(f"--infos: a pose has translation {t!r} and rotation {q!r}: expected 3 numbers and a "
                             "quaternion w x y z") from None
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.linalg.norm(q) > 0):
            raise InputError(f"--infos: a pose has translation {t.tolist()} and rotation {q.tolist()}: not finite, or "
                             "not a rotation")
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rotation_from_quaternion(q), t
        return m

    infos = []
    for f in infos_files:
        try:
            with open(f, "rb") as fh:
                doc = pickle.load(fh)
        except (OSError, pickle.UnpicklingError, EOFError) as exc:
            raise InputError(f"--infos {f}: unreadable ({exc})") from exc
        items = doc.get("infos", doc.get("data_list")) if isinstance(doc, dict) else doc
        if not isinstance(items, list):
            raise InputError(f"--infos {f}: no list of infos ('infos' or 'data_list')")
        infos += items
    by_scene: dict[str, list] = {}
    for info in infos:
        if not isinstance(info, dict):
            raise InputError(f"--infos: an entry is a {type(info).__name__}, not an info dict")
        try:
            lidar_global = pose(info["ego2global_translation"], info["ego2global_rotation"]) @ \
                pose(info["lidar2ego_translation"], info["lidar2ego_rotation"])
            by_scene.setdefault(info["scene_name"], []).append(
                (info["timestamp"], info["token"], lidar_global,
                 pose(info["ego2global_translation"], info["ego2global_rotation"])))
        except KeyError as exc:
            raise InputError(f"--infos: an info lacks {exc} (needs token, scene_name, timestamp, lidar2ego_* and "
                             "ego2global_*)") from None
    return origins_from_poses(by_scene)


def origins_from_poses(by_scene: dict[str, list]) -> dict[str, np.ndarray]:
    """``token -> origins`` from ``scene -> [(timestamp, token, lidar_to_world, ego_to_world)]``."""
    from carlaocc.stages.evaluation.rays import select_origins
    out = {}
    for frames in by_scene.values():
        frames.sort(key=lambda r: r[0])
        positions = np.stack([r[2][:3, 3] for r in frames])
        for _, token, _, ego in frames:
            world_to_ego = np.linalg.inv(ego)
            out[token] = select_origins(positions @ world_to_ego[:3, :3].T + world_to_ego[:3, 3])
    return out


def _root_ground_truth(gt: Path, pred: Path, classes: str, panoptic: bool):
    """A carlaocc root as ground truth: ``(pairs, origins, loader)`` where each pair's ground truth
    is resampled from the root's occupancy onto the Occ3D grid when scored (the prediction tree is
    keyed by the tokens ``<sequence>_<frame:06d>``), origins from the root's poses."""
    from carlaocc.catalog.samples import DatasetError, FrameSamples
    try:
        ds = FrameSamples(str(gt), occupancy="none", cameras=False, lidar=False, boxes=False)
    except DatasetError as exc:
        raise InputError(f"--gt {gt}: {exc}") from None
    pairs, by_scene = [], {}
    index = _root_index(pred, "--pred") if _is_root(pred) else None
    for k, (seq, frame) in enumerate(ds.samples):
        token = f"{seq}_{frame:06d}"
        p = _prediction(pred, seq, token, f"{seq} frame {frame}", index)
        s = ds[k]
        pairs.append((seq, token, p, (ds, k)))
        by_scene.setdefault(seq, []).append((s["timestamp"], token, s["lidar_pose"], s["ego_pose"]))
    return pairs, origins_from_poses(by_scene)


def _root_frame(ds, k: int, classes: str, panoptic: bool) -> dict[str, np.ndarray]:
    """One root frame on the Occ3D grid (ego frame, 0.4 m) in ``classes``' ids: semantics, and
    instances and flow (vx, vy m/s) for RayPQ / mAVE."""
    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.catalog.store import Store
    from carlaocc.pipeline.commands.export.spec import built_label_table, scenes_label_tables
    from carlaocc.stages.export.resample import OCC3D_NUSCENES, OPENOCC_V2, resample, resample_panoptic
    seq, frame = ds.samples[k]
    store = Store(ds.root)
    occ = OccupancyStore(store)
    grid = ds.grid(seq)
    table = built_label_table(occ, seq, grid, scenes_label_tables(store)[seq])
    target = OCC3D_NUSCENES if classes == "occ3d" else OPENOCC_V2
    names = tuple(n for n in ("semantic", "instance", "flow") if occ.exists(seq, grid, n))
    data = occ.read_frame(seq, grid, frame, names)
    to_ego = ds[k]["lidar_to_ego"]
    labels, _ = resample(data["semantic"], grid, target, to_ego, label_table=table)
    out = {"semantics": labels}
    if panoptic or (classes == "openocc-v2" and "flow" in data):  # (Occ3D has no flow: skip the work)
        inst, flow = resample_panoptic(data["semantic"], data.get("instance", np.zeros(grid.shape, np.uint32)),
                                       data.get("flow"), grid, target, to_ego, label_table=table)
        out["instances"] = inst
        if flow is not None and classes == "openocc-v2":
            out["flow"] = flow[..., :2]
    return out


def _ray_eval(pred: Path, gt: Path, infos: list[Path] | None, classes: str, relative: bool, origin: str | None,
              panoptic: bool, json_out: Path | None) -> None:
    from carlaocc.stages.evaluation.rays import RayAccumulator

    if classes not in RAY_CLASSES:
        raise InputError(f"--classes {classes!r}: one of {', '.join(RAY_CLASSES)}")
    names = list(taxonomy.TARGETS[RAY_CLASSES[classes]])
    root_gt = _is_root(gt)  # a carlaocc root, not an Occ3D tree
    if root_gt:
        pairs, origins = _root_ground_truth(gt, pred, classes, panoptic)
        infos = infos or [gt]  # the root's poses give the standard origins
    else:
        pairs = ray_pairs(pred, gt)
        origins = ray_origins(infos) if infos else {}
    fallback = None
    if infos:
        origin_doc = {"source": "root poses" if root_gt else "infos", "per_sample": "up to 8"}
        why = (f"the LiDAR positions of each scene's frames ({'the root' if root_gt else '--infos'} poses), up to 8 "
               "per sample: SparseOcc's protocol")
    else:
        if origin is None:
            xyz, source = LIDAR2EGO[classes], "lidar2ego"
            why = (f"one origin per sample at nuScenes' LIDAR_TOP lidar2ego translation {list(xyz)} m (no --infos: "
                   "SparseOcc's origin for a sample alone in its scene; with --infos, up to 8 LiDAR positions of the "
                   "scene's frames)")
        else:
            try:
                xyz = tuple(float(v) for v in origin.split(","))
                if len(xyz) != 3:
                    raise ValueError
            except ValueError:
                raise InputError(f"--origin {origin!r}: x,y,z in metres") from None
            source = "--origin"
            why = f"one origin per sample at --origin {list(xyz)} m: NOT the standard protocol (pass --infos)"
        fallback = np.array(xyz, float).reshape(1, 3)
        origin_doc = {"source": source, "per_sample": 1, "xyz": list(xyz)}
    typer.echo(f"origins: {why}")
    things = tuple(names.index(n) for n in RAY_THINGS)
    acc = RayAccumulator(names, thing_classes=things, relative=relative, flow_classes=things)
    grid_origin, voxel = (-40.0, -40.0, -1.0), 0.4
    for scene, token, p, g in pairs:
        g_arr = _root_frame(*g, classes, panoptic) if root_gt else load_arrays(g)
        p_arr = _root_frame(*p, classes, panoptic) if isinstance(p, tuple) else load_arrays(p)
        gsem = g_arr.get("semantics")
        psem = p_arr.get("semantics", p_arr.get("pred", next(iter(p_arr.values())) if len(p_arr) == 1 else None))
        if gsem is None or psem is None:
            raise InputError(f"{g if gsem is None else p}: no 'semantics' (or 'pred') array")
        for arr, f in ((gsem, g), (psem, p)):
            if not np.issubdtype(arr.dtype, np.integer):
                raise InputError(f"{f if not isinstance(f, tuple) else '--gt'}: semantics must be integers, got {arr.dtype}")
        if gsem.shape != (200, 200, 16) or psem.shape != gsem.shape:
            raise InputError(f"{p}: shape {psem.shape} against the ground truth's {gsem.shape} (the 200 x 200 x 16 "
                             "grid at 0.4 m)")
        gi = pi = None
        if panoptic:
            gi, pi = g_arr.get("instances"), p_arr.get("instances", p_arr.get("pano_inst"))
            if gi is None or pi is None:
                raise InputError(f"{g if gi is None else p}: no 'instances' array (RayPQ needs them on both sides)")
        if infos and token not in origins:
            raise InputError(f"--infos has no sample {token} (of {g})")
        gf, pf = g_arr.get("flow"), p_arr.get("flow")  # OpenOcc v2: (X, Y, Z, 2) m/s
        if (gf is None) != (pf is None) and gf is not None:
            raise InputError(f"{p}: the ground truth has 'flow' and the prediction none (mAVE needs both)")
        try:
            acc.update(gsem.astype(np.int64), psem.astype(np.int64), origins[token] if infos else fallback,
                       grid_origin, voxel, gi, pi, gf, pf)
        except ValueError as exc:
            raise InputError(f"{p}: {exc}") from exc
    if acc.rays == 0:
        raise InputError("no ray of the ground truth hit anything: check the origins (--infos poses, --origin) and "
                         "that the ground truth is not all free")
    iou = acc.ray_iou()
    protocol = ("sparseocc" if infos else "sparseocc (lone sample: lidar2ego origin)" if origin is None else
                "single origin (not the standard protocol)")
    doc = {"samples": len(pairs), "rays": acc.rays, "classes": classes, "protocol": protocol, "origins": origin_doc,
           **iou.to_dict()}
    rows = [("RayIoU", iou.by_threshold, iou.ray_iou)]
    if panoptic:
        pq = acc.ray_pq()
        doc.update(pq.to_dict())
        rows.append(("RayPQ", pq.by_threshold, pq.ray_pq))
    flow_line = ""
    if acc.has_flow:
        m, per = acc.mave()
        doc.update({"mAVE": m, "AVE_per_class": per, "occupancy_score": acc.occupancy_score()})
        flow_line = f"mAVE {m:.4f} m/s (TP rays at 2 m of the road users), occupancy score {acc.occupancy_score():.4f}"
        if not relative:
            flow_line += " (OccNet's challenge score also accepts 10 % relative depth errors: --relative)"
    typer.echo(f"{len(pairs)} samples, {acc.rays:,} rays kept ({iou.variant}{'' if infos else ', one origin a sample'})")
    typer.echo(f"{'class':22s} {'@1':>7s} {'@2':>7s} {'@4':>7s}  gt rays")
    for i, c in enumerate(iou.classes):
        if iou.gt_rays[i] or np.isfinite(iou.iou[:, i]).any():
            typer.echo(f"{c:22s} " + " ".join(percent(float(iou.iou[k, i])) + " " for k in range(3)) + f" {int(iou.gt_rays[i]):,}")
    for name, by, mean in rows:
        typer.echo(f"{name:22s} " + " ".join(percent(by[t]) + " " for t in (1.0, 2.0, 4.0)) + f" mean {percent(mean)}")
    if flow_line:
        typer.echo(flow_line)
    write_json(json_out, finite_json(doc))


InfosOpt = Annotated[Optional[list[Path]], typer.Option("--infos", help="info pickle(s) with the samples' poses (carlaocc export mmdet3d-infos, or BEVDet/SparseOcc infos): ray origins at up to 8 LiDAR positions of each scene, SparseOcc's protocol")]
ClassesOpt = Annotated[str, typer.Option("--classes", help="occ3d (18, free 17) | openocc-v2 (17, free 16)")]
RelativeOpt = Annotated[bool, typer.Option("--relative", help="OccNet's variant: a ray within 10 %% of the ground-truth depth is also a hit")]
OriginOpt = Annotated[Optional[str], typer.Option("--origin", help="without --infos: the one ray origin of each sample, x,y,z m in the grid's (ego) frame (not the standard protocol); default: nuScenes' LIDAR_TOP lidar2ego translation 0.985793,0,1.84019, SparseOcc's origin for a sample alone in its scene")]


@eval_app.command("rayiou")
def rayiou_cmd(pred: Annotated[Path, typer.Option("--pred", help="predictions: a tree <scene>/<token>/labels.npz (semantics) or <token>.npz (pred), or a carlaocc root")],
               gt: Annotated[Path, typer.Option("--gt", help="ground truth: an Occ3D tree <scene>/<token>/labels.npz, or a carlaocc root (resampled onto the Occ3D grid, origins from its poses; predictions keyed <sequence>_<frame:06d>)")],
               infos: InfosOpt = None, classes: ClassesOpt = "occ3d", relative: RelativeOpt = False,
               origin: OriginOpt = None, json_out: JsonOpt = None) -> None:
    """RayIoU (SparseOcc): per-class IoU of the first hits of 14,040 query rays from up to 8
    origins per sample, a hit counting when the class agrees and the depth is within 1, 2 or 4 m;
    RayIoU@1/@2/@4 and their mean. Origins: the scenes' LiDAR positions from --infos (or a root's
    poses); without them, each sample's lidar2ego translation (nuScenes' LIDAR_TOP), as SparseOcc
    for a sample alone in its scene. The output says which. With a 'flow' array on both sides (OpenOcc v2), also mAVE and
    the occupancy score 0.9 RayIoU + 0.1 max(1 - mAVE, 0)."""
    run_checked(lambda: _ray_eval(pred, gt, infos, classes, relative, origin, False, json_out))


@eval_app.command("raypq")
def raypq_cmd(pred: Annotated[Path, typer.Option("--pred", help="prediction tree with semantics and instances")],
              gt: Annotated[Path, typer.Option("--gt", help="ground truth: an Occ3D tree with semantics and instances, or a carlaocc root")],
              infos: InfosOpt = None, classes: ClassesOpt = "occ3d", relative: RelativeOpt = False,
              origin: OriginOpt = None, json_out: JsonOpt = None) -> None:
    """RayPQ (SparseOcc) beside RayIoU: ray segments (one per thing instance, one per stuff class
    and sample) matched at IoU > 0.5 within each depth threshold; segments under 10 rays are never
    counted as errors."""
    run_checked(lambda: _ray_eval(pred, gt, infos, classes, relative, origin, True, json_out))
