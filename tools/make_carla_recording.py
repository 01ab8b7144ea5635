"""Writes a small CARLA recording in the layout and encodings of the CarlaOcc authors' data
collection and scene export (fengyi233/carlaocc: ``data_collection/src/data_saver.py``,
``utils/transforms.py``, ``scene_exportation/``), so the ``carla-recording`` importer is tested on
files no part of the carlaocc pipeline wrote. Only numpy, PyYAML and Pillow are used here: the
scene is boxes and planes, ray-cast by the small Moller-Trumbore caster below.

Usage: ``python tools/make_carla_recording.py OUT [--frames 6] [--size 176x48]`` writes::

    OUT/calib/calib.yaml
    OUT/SceneMeshes/Town99_Opt/{exported_scene_info.json, actor_info.json, bg_actors/*.obj}
    OUT/SceneMeshes/fg_actors/Car/vehicle_*.obj
    OUT/SceneMeshes/fg_actors/Pedestrians/{frame_info.json, standard_walking/frame_XX.obj, frame_XX_bones.json}
    OUT/Town99_Opt_Seq00/poses/{cam_00.txt, lidar.txt}
    OUT/Town99_Opt_Seq00/traffic_info/%04d.yaml
    OUT/Town99_Opt_Seq00/rgb/image_00..05, image_bev/%04d.png
    OUT/Town99_Opt_Seq00/{depth_carla, semantics_carla}/image_00..05/%04d.png
    OUT/Town99_Opt_Seq00/{lidar, semantic_lidar}/%04d.ply

The scene (right-handed world, x forward, y left, z up, metres): a 14 m road along x with a
centre line, raised sidewalks both sides, a building and a pole on the left, a split terrain
landscape; the ego drives +x in the right lane at 5 m/s, turning slightly; car 245 drives ahead of
it in the same lane, car 246 comes the other way in the left lane (so left must stay left);
walker 301 walks +x on the right sidewalk, its legs swinging with its gait (phase
:func:`walker_phase`). Encodings as the saver
writes them: frame numbers ``%04d``; pose lines ``%04d`` then 16 ``%.6f`` (sensor-to-world,
right-handed: CARLA's y, pitch and yaw negated); traffic YAML in the saver's key order with
floats rounded to 6 decimals; RGB with the x1.2 gain; raw depth ``clip(d, 0, 80) / 80 * 65535``
as uint16 (planar depth); raw semantics in CARLA's CityScapes palette, the terrain unlabelled (black)
as CARLA's semantic pass leaves it; ASCII PLY with y negated.
Meshes: OBJ in the export's mesh axes (x forward, y up, z right; world = (x, -z, y)), metres,
background actors placed in the world, vehicles in their actor frame, the walk cycle's frames
in the skeletal mesh's component frame (feet at the origin, walking along +z of the mesh axes)
with their bone files in the mesh axes in centimetres. The recorded leg bones (``crl_leg__L/R``,
the lower legs: origins at the knees) are socket transforms in the walker's actor frame (x
forward, origin the box centre), metres, as CARLA's ``GetBonesTransform`` gives them.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

TOWN = "Town99_Opt"
SEQUENCE = f"{TOWN}_Seq00"
FPS = 10.0
FOV = 103.744808  # deg, the rig's cameras
LIDAR_Z = 1.73  # m above the ego origin
# camera mounts (CARLA frame: y right; metres, yaw degrees) as the authors' sensor config
CAMERAS = {"00": (0.8, -0.3, 1.55, 0.0), "01": (0.8, 0.3, 1.55, 0.0), "02": (0.0, -0.46, 1.55, -90.0),
           "03": (0.0, 0.46, 1.55, 90.0), "04": (-0.8, -0.3, 1.55, 180.0), "05": (-0.8, 0.3, 1.55, 180.0)}
# CARLA CityScapes palette (utils/labels.py), by id
PALETTE = {0: (0, 0, 0), 1: (128, 64, 128), 2: (244, 35, 232), 3: (70, 70, 70), 6: (153, 153, 153),
           10: (152, 251, 152), 11: (70, 130, 180), 12: (220, 20, 60), 14: (0, 0, 142), 24: (157, 234, 50)}
NAMES = {1: "Road", 2: "Sidewalk", 3: "Building", 6: "Pole", 10: "Terrain", 24: "RoadLine", 12: "Pedestrian", 14: "Car"}
OBJ_TO_WORLD = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # world = (x, -z, y) of the mesh axes
FLIP = np.diag([1.0, -1.0, 1.0, 1.0])  # left- <-> right-handed (CARLA y right <-> y left)


# ------------------------------------------------------------------ geometry

def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Closed box, outward triangles."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    V = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], dtype=float)
    F = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                  [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return V, F


def quad(x0, x1, y0, y1, z, n=1) -> tuple[np.ndarray, np.ndarray]:
    """Upward-facing rectangle at height z split into n x n cells."""
    xs, ys = np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1)
    V = np.array([[x, y, z] for y in ys for x in xs], dtype=float)
    F = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            F += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return V, np.array(F)


def merge(parts):
    Vs, Fs, off = [], [], 0
    for V, F in parts:
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    return np.concatenate(Vs), np.concatenate(Fs)


def transform(T, V):
    return V @ T[:3, :3].T + T[:3, 3]


def pose(x, y, z, yaw) -> np.ndarray:
    """Right-handed 4x4 at (x, y, z) turned by yaw rad about +z."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, z], [0, 0, 0, 1.0]])


def write_obj(path: Path, V_world: np.ndarray, F: np.ndarray) -> None:
    """OBJ in the export's mesh axes (x forward, y up, z right), 6 digits (trimesh's writer)."""
    V = V_world @ OBJ_TO_WORLD  # inverse of world = OBJ_TO_WORLD @ v (a rotation)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")


def ray_cast(origins, dirs, tris, labels):
    """Nearest hit distance (inf: none) and label per ray (Moller-Trumbore, vectorized)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = b - a, c - a
    best = np.full(len(dirs), np.inf)
    lab = np.zeros(len(dirs), dtype=np.int64)
    for k in range(0, len(dirs), 2048):
        d = dirs[k:k + 2048, None, :]
        o = origins[k:k + 2048, None, :]
        p = np.cross(d, e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - a[None]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("rtk,rtk->rt", d, q) * inv
        t = np.einsum("tk,rtk->rt", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
        t = np.where(hit, t, np.inf)
        i = np.argmin(t, axis=1)
        best[k:k + 2048] = t[np.arange(len(i)), i]
        lab[k:k + 2048] = np.where(np.isfinite(best[k:k + 2048]), labels[i], 11)  # sky
    return best, lab


# ------------------------------------------------------------------ the scene

def static_actors():
    """(name, label, instance id, world vertices, faces) of the background actors."""
    out = [
        ("Road_Road_Town99_1", "Road", 0, *quad(-40.0, 60.0, -7.0, 7.0, 0.0, 4)),
        ("Road_RoadLine_Town99_1", "RoadLine", 0, *quad(-40.0, 60.0, -0.08, 0.08, 0.01, 1)),
        ("Sidewalk_Left", "Sidewalk", 0, *box((-40.0, 7.0, -0.2), (60.0, 10.0, 0.15))),
        ("Sidewalk_Right", "Sidewalk", 0, *box((-40.0, -10.0, -0.2), (60.0, -7.0, 0.15))),
        ("BP_Apartment01", "Building", 1, *box((10.0, 12.0, 0.0), (20.0, 20.0, 8.0))),
        ("BP_StreetLight_1", "Pole", 1, *box((4.9, 7.5, 0.15), (5.1, 7.7, 5.0))),
    ]
    return out


def landscape():
    """A terrain sheet larger than 50 m both ways: split into 50 m cells by face centroid from
    the sheet's minimum (the export's large-actor tiling)."""
    V, F = quad(-60.0, 80.0, -60.0, 60.0, -0.05, 6)
    cent = V[F].mean(axis=1)
    ix = np.floor((cent[:, 0] - V[:, 0].min()) / 50.0).astype(int)
    iy = np.floor((cent[:, 1] - V[:, 1].min()) / 50.0).astype(int)
    tiles = []
    for cx in np.unique(ix):
        for cy in np.unique(iy):
            sel = F[(ix == cx) & (iy == cy)]
            if len(sel):
                used = np.unique(sel)
                remap = -np.ones(len(V), dtype=int)
                remap[used] = np.arange(len(used))
                tiles.append((f"Landscape_split_x{cx:03d}_y{cy:03d}", V[used], remap[sel]))
    return (V, F), tiles


def car_model(length=4.8, width=2.0, height=1.5):
    """A car in its actor frame (origin on the ground under the box centre shifted 0.1 m back)."""
    body = box((-length / 2 + 0.1, -width / 2, 0.3), (length / 2 + 0.1, width / 2, 0.9))
    cabin = box((-1.2, -width / 2 + 0.1, 0.9), (1.0, width / 2 - 0.1, height))
    wheels = [box((x - 0.35, y - 0.15, 0.0), (x + 0.35, y + 0.15, 0.7)) for x in (-1.4, 1.6) for y in (-0.8, 0.8)]
    return merge([body, cabin, *wheels])


def _ry(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about +y (right-handed)."""
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +90 deg about z


def walker_pose(phase: float, height=1.8):
    """The walker at gait ``phase`` (0..1) in its actor axes (x forward, y left, z up) with the
    feet at z = 0: (vertices, faces, {bone: (knee position, lower-leg rotation)}). The thighs swing
    +-0.45 rad opposite each other (the left forward first), the knees bend in the swing phase;
    CARLA's ``crl_leg__L/R`` are the lower legs, their origins the knees."""
    leg = 0.5 * height
    parts = [box((-0.12, -0.18, leg), (0.12, 0.18, height - 0.25)), box((-0.1, -0.1, height - 0.25), (0.1, 0.1, height))]
    bones = {}
    for name, side, sign in (("crl_leg__L", 1.0, 1.0), ("crl_leg__R", -1.0, -1.0)):
        thigh = sign * 0.45 * math.sin(2 * math.pi * phase)  # rad, foot forward when positive
        bend = 0.25 * (1.0 + math.sin(2 * math.pi * phase * sign + math.pi / 2 * sign))  # knee flexion
        hip = np.array([0.0, 0.1 * side, leg])
        R_thigh, R_shin = _ry(-thigh), _ry(-(thigh - bend))
        knee = hip + R_thigh @ np.array([0.0, 0.0, -leg / 2])
        foot = knee + R_shin @ np.array([0.0, 0.0, -leg / 2])
        for a, b in ((hip, knee), (knee, foot)):
            parts.append(box(np.minimum(a, b) - 0.06, np.maximum(a, b) + 0.06))
        bones[name] = (knee, R_shin)
    V, F = merge(parts)
    return V, F, bones


def walker_phase(t: float) -> float:
    """Walker 301's gait phase (0..1) at ``t`` s: the truth a phase matcher is measured against."""
    return (0.3 + 1.4 * t) % 1.0


# ------------------------------------------------------------------ encodings

def fmt6(x):
    """The saver's formatter: 6 decimals, trailing zeros stripped."""
    if isinstance(x, dict):
        return {k: fmt6(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [fmt6(v) for v in np.asarray(x).tolist()] if isinstance(x, np.ndarray) else [fmt6(v) for v in x]
    if isinstance(x, float):
        return float(f"{x:.6f}")
    return x


def pose_line(frame: int, M: np.ndarray) -> str:
    return f"{frame:04d} " + " ".join(f"{v:.6f}" for v in M.astype(np.float32).flatten()) + "\n"


def write_ply(path: Path, pts: np.ndarray, extra: list[tuple[str, str]], fmt: str) -> None:
    head = ["ply", "format ascii 1.0", f"element vertex {len(pts)}"]
    head += [f"property {t} {n}" for t, n in [("float32", "x"), ("float32", "y"), ("float32", "z")] + extra]
    with path.open("w") as fh:
        fh.write("\n".join(head + ["end_header"]) + "\n")
        np.savetxt(fh, pts, fmt=fmt)


def cam_to_lidar(cam: str) -> np.ndarray:
    """Camera-to-LiDAR (right-handed, both frames x forward, y left, z up)."""
    x, y, z, yaw = CAMERAS[cam]
    return pose(x, -y, z - LIDAR_Z, -math.radians(yaw))


# ------------------------------------------------------------------ the recording

def make(out: Path, frames: int = 6, size=(176, 48)) -> None:
    W, H = size
    out.mkdir(parents=True, exist_ok=True)
    fx = (W / 2) / math.tan(math.radians(FOV) / 2)
    K = [[fx, 0.0, W / 2], [0.0, fx, H / 2], [0.0, 0.0, 1.0]]
    (out / "calib").mkdir(exist_ok=True)
    calib = {"cam_settings": {"width": W, "height": H, "fov": FOV, "intrinsics": K},
             "sensors": {f"cam_{c}": {"transform": cam_to_lidar(c).tolist()} for c in CAMERAS}}
    (out / "calib" / "calib.yaml").write_text(yaml.dump(fmt6(calib), sort_keys=False))

    # background actors: OBJ per actor, the landscape split, actor_info and the scene info
    scene_dir = out / "SceneMeshes" / TOWN
    bg = scene_dir / "bg_actors"
    bg.mkdir(parents=True, exist_ok=True)
    actors = static_actors()
    (LV, LF), tiles = landscape()
    write_obj(bg / "Landscape.obj", LV, LF)  # the unsplit file stays on disk, unlisted
    exported, infos = [], []
    for name, label, inst, V, F in actors + [(n, "Terrain", 0, V, F) for n, V, F in tiles]:
        write_obj(bg / f"{name}.obj", V, F)
        base = "Landscape" if name.startswith("Landscape") else name
        if not any(e["name"] == base for e in exported):
            exported.append({"name": base, "label": base, "semantic_label": label, "ue_class": "StaticMeshActor"})
        lo, hi = V.min(axis=0), V.max(axis=0)
        infos.append({"idx": next(i for i, e in enumerate(exported) if e["name"] == base), "instance_id": inst,
                      "name": name, "label": base, "exported_file": f"{name}.obj", "semantic_label": label,
                      "ue_class": "StaticMeshActor", "vertex_count": len(V), "face_count": len(F),
                      "center": ((lo + hi) / 2).tolist(), "bbox_min": lo.tolist(), "bbox_max": hi.tolist(),
                      "dimensions": (hi - lo).tolist(), "has_voxelization": True})
    counts: dict[str, int] = {}
    for i in infos:
        counts[i["semantic_label"]] = counts.get(i["semantic_label"], 0) + (i["instance_id"] > 0)
    (scene_dir / "exported_scene_info.json").write_text(json.dumps(
        {"map_name": TOWN, "exported_actors_dir": f"/home/someone/CarlaOcc/SceneMeshes/{TOWN}/bg_actors",
         "valid_actor_number": len(exported), "actors": exported}, indent=4))
    (scene_dir / "actor_info.json").write_text(json.dumps(
        {"statistics": {"total_actors": len(infos), "instance_counts": counts, "total_instances": sum(counts.values())},
         "actors": fmt6(infos)}, indent=4))

    # foreground actors: vehicle models by blueprint (actor frame), the walk cycle
    fg = out / "SceneMeshes" / "fg_actors"
    (fg / "Car").mkdir(parents=True, exist_ok=True)
    car_V, car_F = car_model()
    for bp in ("vehicle_taxi_ford", "vehicle_lincoln_mkz", "vehicle_mini_cooper"):
        write_obj(fg / "Car" / f"{bp}.obj", car_V, car_F)
    walk = fg / "Pedestrians" / "standard_walking"
    walk.mkdir(parents=True, exist_ok=True)
    (fg / "Pedestrians" / "frame_info.json").write_text(json.dumps({"AS_walking04_G3": 36}, indent=4))
    for i in range(36):
        V, F, bones = walker_pose(i / 36)
        # the walk cycle's frames: the component frame is the actor's turned -90 deg (walking
        # along -y), written in the mesh axes (walking along +z) at scale 1; the bone files hold
        # the same bones in the mesh axes in centimetres (the animation's units)
        write_obj(walk / f"frame_{i:02d}.obj", V @ RZ90, F)
        to_mesh = OBJ_TO_WORLD.T @ RZ90.T  # actor axes -> mesh axes
        cycle_bones = {}
        for k, (knee, R) in bones.items():
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = to_mesh @ R @ to_mesh.T, to_mesh @ knee * 100.0
            cycle_bones[k] = T.tolist()
        (walk / f"frame_{i:02d}_bones.json").write_text(json.dumps(cycle_bones))

    # the sequence: world geometry with labels for the sensors
    seq = out / SEQUENCE
    for stale in (seq / "poses").glob("*.txt"):  # the saver starts its pose files afresh (append mode)
        stale.unlink()
    for d in ["poses", "traffic_info", "lidar", "semantic_lidar", "rgb/image_bev"] + [
            f"{k}/image_{c}" for k in ("rgb", "depth_carla", "semantics_carla") for c in CAMERAS]:
        (seq / d).mkdir(parents=True, exist_ok=True)
    static_parts = [(V, F, {"Road": 1, "RoadLine": 24, "Sidewalk": 2, "Building": 3, "Pole": 6}[label])
                    for _, label, _, V, F in actors] + [(LV, LF, 10)]
    ego_bbox = (np.array([2.4, 1.0, 0.75]), pose(0.1, 0.0, 0.75, 0.0))
    for f in range(frames):
        t = f / FPS
        # the ego and the cars turn a little (no rotation here is its own transpose)
        ego = pose(-10.0 + 5.0 * t, -1.75 + 0.05 * t, 0.0, 0.01 + 0.02 * t)
        cars = {245: ("vehicle.lincoln.mkz", pose(4.0 + 6.0 * t, -1.75, 0.0, 0.05), [6.0, 0.3, 0.0]),
                246: ("vehicle.mini.cooper", pose(25.0 - 7.0 * t, 1.75, 0.0, math.pi - 0.08), [-7.0, 0.56, 0.0])}
        phase = walker_phase(t)
        walker_T = pose(-6.0 + 1.4 * t, -8.5 + 0.04 * t, 0.15 + 0.9, 0.03)  # CARLA walker origin: the box centre
        wV, wF, wbones = walker_pose(phase)
        parts = list(static_parts)
        for _, T, _ in cars.values():
            parts.append((transform(T, car_V), car_F, 14))
        parts.append((transform(walker_T @ pose(0.0, 0.0, -0.9, 0.0), wV), wF, 12))
        tris = np.concatenate([V[F] for V, F, _ in parts])
        labels = np.concatenate([np.full(len(F), lab) for _, F, lab in parts])
        lidar = ego @ pose(0.0, 0.0, LIDAR_Z, 0.0)
        for name, M in (("lidar", lidar), ("cam_00", lidar @ cam_to_lidar("00"))):
            with (seq / "poses" / f"{name}.txt").open("a") as fh:
                fh.write(pose_line(f, M))
        # traffic_info: CARLA's left-handed transforms converted with diag(1,-1,1,1) M diag(1,-1,1,1)
        # (our poses are right-handed already: the conversion has been applied)
        info = {"ego_vehicles": {"id": 231, "type": "vehicle.taxi.ford", "velocity": [5.0, 0.05, 0.0],
                                 "acceleration": [0.0, 0.0, 0.0], "angular_velocity": [0.0, 0.0, 0.0]},
                "vehicles": [], "pedestrians": []}
        for cid, (bp, T, vel) in cars.items():
            info["vehicles"].append({"id": cid, "type": bp, "transform": T.tolist(),
                                     "distance_to_ego": float(np.linalg.norm(T[:3, 3] - ego[:3, 3])), "velocity": vel,
                                     "bbox": {"extent": ego_bbox[0].tolist(), "transform": ego_bbox[1].tolist()}})
        # the recorded leg bones: socket transforms in the actor frame (origin the box centre), metres
        bones_m = {}
        for k, (knee, R) in wbones.items():
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, knee - [0.0, 0.0, 0.9]
            bones_m[k] = T
        info["pedestrians"].append({"id": 301, "type": "walker.pedestrian.0012", "transform": walker_T.tolist(),
                                    "distance_to_ego": float(np.linalg.norm(walker_T[:3, 3] - ego[:3, 3])),
                                    "bbox_extent": [0.25, 0.25, 0.9], "bones": {k: v.tolist() for k, v in bones_m.items()}})
        (seq / "traffic_info" / f"{f:04d}.yaml").write_text(yaml.dump(fmt6(info), sort_keys=False))
        # cameras: planar depth, palette semantics, RGB with the saver's x1.2 gain
        u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        opt = np.stack([(u - W / 2) / fx, (v - H / 2) / fx, np.ones_like(u)], axis=-1).reshape(-1, 3)
        sensor_dirs = np.stack([opt[:, 2], -opt[:, 0], -opt[:, 1]], axis=1)  # optical -> x fwd, y left, z up
        for c in CAMERAS:
            C = lidar @ cam_to_lidar(c)
            d = sensor_dirs @ C[:3, :3].T
            n = np.linalg.norm(d, axis=1, keepdims=True)
            dist, lab = ray_cast(np.broadcast_to(C[:3, 3], d.shape), d / n, tris, labels)
            depth = np.where(np.isfinite(dist), dist / n[:, 0], 1000.0)  # planar: along the optical axis
            png = (np.clip(depth, 0, 80) / 80 * 65535).astype(np.uint16).reshape(H, W)
            Image.fromarray(png).save(seq / "depth_carla" / f"image_{c}" / f"{f:04d}.png")
            # CARLA's semantic pass leaves the landscape unlabelled (None, black): the artefact the
            # release's rectification repairs (its rectified semantics turn None into Terrain)
            col = np.array([PALETTE[0 if int(k) == 10 else int(k)] for k in lab], dtype=np.uint8).reshape(H, W, 3)
            Image.fromarray(col).save(seq / "semantics_carla" / f"image_{c}" / f"{f:04d}.png")
            shade = np.clip(1.0 - np.where(np.isfinite(dist), dist, 80.0) / 120.0, 0.3, 1.0)[:, None]
            rgb = np.clip(np.array([PALETTE[int(k)] for k in lab]) * shade * 1.2, 0, 255).astype(np.uint8)
            Image.fromarray(rgb.reshape(H, W, 3)).save(seq / "rgb" / f"image_{c}" / f"{f:04d}.png")
        Image.fromarray(np.full((64, 64, 3), 90, np.uint8)).save(seq / "rgb" / "image_bev" / f"{f:04d}.png")
        # LiDAR: 16 channels x 180 azimuths in the sensor frame
        el, az = np.meshgrid(np.radians(np.linspace(-30.0, 10.0, 16)), np.radians(np.arange(0.0, 360.0, 2.0)))
        beams = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
        dist, lab = ray_cast(np.broadcast_to(lidar[:3, 3], beams.shape), beams @ lidar[:3, :3].T, tris, labels)
        keep = np.isfinite(dist) & (dist < 80.0)
        carla_pts = beams[keep] * dist[keep, None] * [1.0, -1.0, 1.0]  # what CARLA's LiDAR gives (y right)
        pts = carla_pts * [1.0, -1.0, 1.0]  # the saver negates y
        write_ply(seq / "lidar" / f"{f:04d}.ply", np.column_stack([pts, np.ones(len(pts))]),
                  [("float32", "I")], "%.4f %.4f %.4f %.4f")
        obj_idx = np.zeros(len(pts), dtype=int)
        sem = np.column_stack([pts, np.ones(len(pts)), obj_idx, lab[keep]])
        with (seq / "semantic_lidar" / f"{f:04d}.ply").open("w") as fh:
            fh.write("\n".join(["ply", "format ascii 1.0", f"element vertex {len(pts)}", "property float x",
                                "property float y", "property float z", "property float CosAngle",
                                "property int ObjIdx", "property int ObjTag", "end_header"]) + "\n")
            np.savetxt(fh, sem, fmt="%.4f %.4f %.4f %.4f %d %d")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="Write a small CARLA recording in the CarlaOcc release layout.")
    ap.add_argument("out", help="output directory")
    ap.add_argument("--frames", type=int, default=6, help="frames of the sequence (default 6)")
    ap.add_argument("--size", default="176x48", help="camera image size WxH (default 176x48)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    make(Path(args.out), args.frames, (w, h))
    print(f"wrote {args.out}")
