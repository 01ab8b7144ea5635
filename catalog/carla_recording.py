"""CARLA recordings in the CarlaOcc release layout: the one place that knows those files.

The layout (the CarlaOcc authors' data collection, scene export and release: fengyi233/carlaocc
``data_collection/src/data_saver.py``, ``utils/transforms.py``, ``utils/load_utils.py``,
``scene_exportation/``; checked fact by fact there, written anew here)::
    <root>/calib/calib.yaml                       cameras: size, fov, intrinsics, camera-to-LiDAR
    <root>/SceneMeshes/<Town>_Opt/actor_info.json the static actors: name, class, instance id,
                                                  OBJ file, world bounds
    <root>/SceneMeshes/<Town>_Opt/bg_actors/*.obj each static actor placed in the world
    <root>/SceneMeshes/fg_actors/<Class>/<blueprint>.obj   vehicle models in their actor frame
    <root>/<Town>_Opt_Seq<NN>/poses/lidar.txt     one line per frame: %04d frame, 16 %.6f (4x4
                                                  row-major LiDAR-to-world)
    <root>/<Town>_Opt_Seq<NN>/poses/cam_00.txt    the same for camera 00 (not needed: calib)
    <root>/<Town>_Opt_Seq<NN>/traffic_info/%04d.yaml   ego, vehicles and pedestrians of the frame
    <root>/<Town>_Opt_Seq<NN>/rgb/image_00..05/%04d.png    RGB (the saver's x1.2 gain, kept)
    <root>/<Town>_Opt_Seq<NN>/depth_carla/image_XX/%04d.png    raw planar depth, uint16,
                                                  clip(d, 0, 80) / 80 * 65535
    <root>/<Town>_Opt_Seq<NN>/semantics_carla/image_XX/%04d.png  raw labels, CityScapes colours
    <root>/<Town>_Opt_Seq<NN>/depth/, semantics/  the release's rectified maps (same encodings)
    <root>/<Town>_Opt_Seq<NN>/lidar/, semantic_lidar/%04d.ply  ASCII PLY, sensor frame, y negated

Frames and axes. The files are already right-handed (x forward, y left, z up, metres): the saver
turned CARLA's left-handed transforms ``M`` into ``diag(1,-1,1,1) M diag(1,-1,1,1)`` (location y,
pitch and yaw negated), which is our world frame and our LiDAR frame. Three exceptions are
converted here, once: **meshes** are in the export's mesh axes (x forward, y up, z right), so a
vertex ``v`` is ``(v_x, -v_z, v_y)`` in our frame (a rotation, windings kept); **PLY points** are
CARLA's sensor-frame points with y negated by the saver -- already ours; **camera poses** are
x-forward bodies, so the OpenCV optical frame is ``pose @ [[0,0,1],[-1,0,0],[0,-1,0]]``. The ego
has no transform of its own: ``ego = lidar_pose @ inv(T(0, 0, 1.73))`` (the LiDAR mount).

Pedestrian bones are the two lower-leg bones ``crl_leg__L`` / ``crl_leg__R`` (their origins are
the knees) as 4x4 socket transforms in the walker's actor frame (CARLA's ``GetBonesTransform``:
``RTS_Actor``; x forward, origin at the box centre; metres, right-handed after the saver's flip).
The walk cycle's bone files hold the same bones in the export's mesh axes (walking along +z),
in centimetres; its meshes are in the skeletal mesh's component frame, which is the actor's
turned -90 degrees about z with the feet at the origin.

The calibration's intrinsics must be CARLA's pinhole of its image size and fov
(:func:`check_intrinsics`, within :data:`INTRINSICS_TOL` px): the rig is built from size and fov.

What is ignored: ``bg_actor_occ/``, ``fg_actor_occ/`` (precomputed voxels: we voxelize the
meshes exactly), ``occupancy/``, ``normal/``, the FBX files, ``rgb/image_bev`` and every absolute
path recorded inside the export's JSON (from the authors' machines). Problems raise
:class:`RecordingError` naming the file (and line) so a batch import can quarantine that item.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from carlaocc.catalog.sources.obj import ObjError, read_obj
from carlaocc.schemas.taxonomy import by_id, by_name

__all__ = [
    "RecordingError", "Calib", "EgoState", "VehicleState", "PedestrianState", "TrafficFrame", "StaticActor",
    "SequenceDir", "Recording", "LIDAR_HEIGHT", "DEPTH_RANGE", "MESH_TO_WORLD", "OPTICAL_FROM_BODY",
    "discover", "model_key", "read_calib", "read_poses", "read_traffic", "read_actor_info", "read_mesh", "read_ply",
    "decode_depth", "decode_semantics", "palette_lookup", "INTRINSICS_TOL", "pinhole", "check_intrinsics",
    "read_scans", "NOT_RECORDED",
]  # fmt: skip

LIDAR_HEIGHT = 1.73  # m: the LiDAR above the ego's origin (the authors' sensor config)
DEPTH_RANGE = 80.0  # m: full scale of the uint16 depth PNGs
MESH_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # (x, y, z)_mesh -> (x, -z, y)
OPTICAL_FROM_BODY = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
SEQUENCE_DIR = re.compile(r"^(?P<town>.+)_Seq(?P<seq>\d+)$")
BONES = ("crl_leg__L", "crl_leg__R")


class RecordingError(ValueError):
    """A recording file that cannot be read: the message names the file (and line)."""


# ------------------------------------------------------------------ records


@dataclass(frozen=True)
class Calib:
    """The cameras: image size (px), horizontal fov (deg), 3x3 intrinsics and each camera's
    body-to-LiDAR transform (x forward, y left, z up), by name ``cam_00`` .. ``cam_05``."""

    width: int
    height: int
    fov_deg: float
    intrinsics: np.ndarray
    cam_to_lidar: dict[str, np.ndarray]


@dataclass(frozen=True)
class EgoState:
    id: int
    type: str
    velocity: np.ndarray | None  # m/s, world (right-handed: the saver negated y); None: not recorded
    acceleration: np.ndarray | None  # m/s2, world; None: not recorded
    angular_velocity: np.ndarray | None  # as recorded (CARLA deg/s, only y negated by the saver)


@dataclass(frozen=True)
class VehicleState:
    id: int
    type: str  # blueprint id, e.g. vehicle.lincoln.mkz
    transform: np.ndarray  # 4x4 actor-to-world
    velocity: np.ndarray  # m/s, world
    extent: np.ndarray  # half extents of the box, m
    bbox_transform: np.ndarray  # 4x4 box-to-actor (the box centre and turn in the actor frame)


@dataclass(frozen=True)
class PedestrianState:
    id: int
    type: str
    transform: np.ndarray  # 4x4 actor-to-world; the actor origin is the box centre
    extent: np.ndarray  # half extents, m
    bones: dict[str, np.ndarray]  # crl_leg__L / crl_leg__R: 4x4 in the actor frame, metres (origins: the knees)


@dataclass(frozen=True)
class TrafficFrame:
    ego: EgoState
    vehicles: tuple[VehicleState, ...]
    pedestrians: tuple[PedestrianState, ...]
    # actors left out of the frame, with the reason (e.g. a non-finite transform)
    skipped: tuple[tuple[int, str], ...] = ()


@dataclass(frozen=True)
class StaticActor:
    """One background actor of ``actor_info.json``: a mesh placed in the world."""

    name: str
    semantic_id: int
    instance_id: int  # 0 for stuff (and split tiles, foliage instances)
    file: Path
    bbox_min: np.ndarray
    bbox_max: np.ndarray


@dataclass(frozen=True)
class SequenceDir:
    """A recorded sequence: ``<Town>_Opt_Seq<NN>`` under the root."""

    name: str
    town: str  # e.g. Town01_Opt
    index: int
    path: Path


@dataclass(frozen=True)
class Recording:
    """What :func:`discover` finds under a root."""

    root: Path
    calib: Path
    sequences: tuple[SequenceDir, ...]
    scene_meshes: dict[str, Path] = field(default_factory=dict)  # town -> SceneMeshes/<town>
    vehicle_models: dict[str, Path] = field(default_factory=dict)  # blueprint id -> OBJ


# ------------------------------------------------------------------ discovery


def discover(root) -> Recording:
    """The sequences, calibration, town meshes and vehicle models under ``root`` (a release
    root, or one sequence directory with ``calib/`` and ``SceneMeshes/`` beside it)."""
    root = Path(root)
    if not root.is_dir():
        raise RecordingError(f"{root}: not a directory (a CARLA recording root holds <Town>_Opt_Seq<NN>/)")
    m = SEQUENCE_DIR.match(root.name)
    if m and (root / "poses").is_dir():
        base, dirs = root.parent, [root]
    else:
        base, dirs = root, sorted(p for p in root.iterdir() if p.is_dir() and SEQUENCE_DIR.match(p.name))
    if not dirs:
        raise RecordingError(f"{root}: no sequence directories (<Town>_Opt_Seq<NN>/ with poses/ and traffic_info/)")
    sequences = []
    for d in dirs:
        mm = SEQUENCE_DIR.match(d.name)
        sequences.append(SequenceDir(name=d.name, town=mm["town"], index=int(mm["seq"]), path=d))
    calib = base / "calib" / "calib.yaml"
    if not calib.is_file():
        raise RecordingError(f"{calib}: missing (the release's calib/calib.yaml: camera size, fov, intrinsics, "
                             f"camera-to-LiDAR transforms)")  # fmt: skip
    meshes = base / "SceneMeshes"
    towns = ({p.name: p for p in sorted(meshes.iterdir()) if p.is_dir() and not p.name.startswith("fg_actor")}
             if meshes.is_dir() else {})  # fmt: skip
    models = {}
    fg = meshes / "fg_actors"
    if fg.is_dir():
        for obj in sorted(fg.glob("*/*.obj")):
            if obj.parent.name != "Pedestrians":  # vehicle models by blueprint (the walk cycle is not one)
                models[model_key(obj.stem)] = obj
    return Recording(root=base, calib=calib, sequences=tuple(sequences), scene_meshes=towns, vehicle_models=models)


def model_key(blueprint: str) -> str:
    """The key of a blueprint's model: the export named ``vehicle.lincoln.mkz``'s file
    ``vehicle_lincoln_mkz.obj``, so ``'.'`` and ``'_'`` count alike."""
    return blueprint.replace("_", ".")


# ------------------------------------------------------------------ small readers


def _yaml(path: Path):
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise RecordingError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: unreadable ({exc})") from None
    except yaml.YAMLError as exc:
        raise RecordingError(f"{path}: not YAML ({str(exc).splitlines()[0]})") from None


def _matrix(value, where: str, shape=(4, 4)) -> np.ndarray:
    what = f"{shape[0]}x{shape[1]} matrix" if len(shape) == 2 else f"{shape[0]}-vector"
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordingError(f"{where}: not a {what} of numbers") from None
    if a.shape != shape:
        raise RecordingError(f"{where}: expected a {what}, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise RecordingError(f"{where}: non-finite values")
    return a


def _vector(value, where: str, n: int = 3) -> np.ndarray:
    return _matrix(value, where, (n,))


def _rigid(T: np.ndarray, where: str, tol: float = 1e-3) -> np.ndarray:
    """``T`` when its 3x3 part is a rotation (to ``tol``: the files keep 6 decimals)."""
    R = T[:3, :3]
    if not (np.allclose(R @ R.T, np.eye(3), atol=tol) and np.linalg.det(R) > 0 and np.allclose(T[3], [0, 0, 0, 1])):
        raise RecordingError(f"{where}: not a rigid transform (rotation part not orthonormal or bottom row not 0 0 0 1)")
    return T


def read_calib(path) -> Calib:
    """``calib/calib.yaml``: ``cam_settings`` (width, height, fov, intrinsics) and
    ``sensors.cam_XX.transform`` (camera-to-LiDAR, 4x4)."""
    path = Path(path)
    data = _yaml(path)
    try:
        cs = data["cam_settings"]
        width, height, fov = int(cs["width"]), int(cs["height"]), float(cs["fov"])
        K = _matrix(cs["intrinsics"], f"{path}: cam_settings.intrinsics", (3, 3))
        sensors = data["sensors"]
        cams = {name: _rigid(_matrix(s["transform"], f"{path}: sensors.{name}.transform"), f"{path}: sensors.{name}")
                for name, s in sensors.items() if str(name).startswith("cam_")}  # fmt: skip
    except (KeyError, TypeError) as exc:
        raise RecordingError(f"{path}: missing key {exc} (expected cam_settings.width/height/fov/intrinsics and "
                             f"sensors.cam_00..cam_05.transform)") from None  # fmt: skip
    if width < 1 or height < 1 or not (0 < fov < 180):
        raise RecordingError(f"{path}: camera size {width}x{height} / fov {fov} out of range")
    if not cams:
        raise RecordingError(f"{path}: no camera transforms under sensors (cam_00 ...)")
    check_intrinsics(K, width, height, fov, str(path))
    return Calib(width=width, height=height, fov_deg=fov, intrinsics=K, cam_to_lidar=dict(sorted(cams.items())))


INTRINSICS_TOL = 0.5  # px: the largest difference allowed between the file's K and CARLA's pinhole


def pinhole(width: int, height: int, fov_deg: float) -> np.ndarray:
    """CARLA's camera intrinsics for an image of ``width`` x ``height`` px and a horizontal field
    of view ``fov_deg``: square pixels, ``f = (width / 2) / tan(fov / 2)`` px, principal point at
    the image centre (``width / 2``, ``height / 2``)."""
    f = (width / 2) / np.tan(np.radians(fov_deg) / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def check_intrinsics(K: np.ndarray, width: int, height: int, fov_deg: float, where: str) -> None:
    """:class:`RecordingError` naming ``where`` when the intrinsics ``K`` are not CARLA's pinhole
    for that image size and fov within :data:`INTRINSICS_TOL` px (focal lengths, principal
    point; the skew and the last row exactly): the rig is built from size and fov, so images
    made with other intrinsics would not line up with our ray-cast maps."""
    want = pinhole(width, height, fov_deg)
    diff = np.abs(np.asarray(K, dtype=np.float64) - want)
    if diff.max() <= INTRINSICS_TOL:
        return
    fov_k = 2 * np.degrees(np.arctan((width / 2) / K[0, 0])) if K[0, 0] > 0 else float("nan")
    raise RecordingError(
        f"{where}: cam_settings.intrinsics (fx {K[0, 0]:.3f}, fy {K[1, 1]:.3f}, cx {K[0, 2]:.3f}, cy {K[1, 2]:.3f}) "
        f"disagree with the image size {width}x{height} and fov {fov_deg:g} deg (fx = fy {want[0, 0]:.3f}, "
        f"cx {want[0, 2]:.3f}, cy {want[1, 2]:.3f}; the intrinsics' fx means a fov of {fov_k:.3f} deg): "
        f"correct cam_settings.width/height/fov or the intrinsics")


def read_poses(path) -> tuple[dict[int, np.ndarray], list[tuple[int, str]]]:
    """A pose file: ``{frame: 4x4 sensor-to-world}`` and the lines left out ``(frame, reason)``
    (non-finite or non-rigid matrices). A line that is not a frame number and 16 numbers raises
    :class:`RecordingError` naming the line; so does a missing file."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise RecordingError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: unreadable ({exc})") from None
    poses, bad = {}, []
    for no, line in enumerate(lines, 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 17:
            raise RecordingError(f"{path}, line {no}: expected a frame number and 16 numbers, got {len(parts)} fields")
        try:
            frame = int(parts[0])
            values = np.array([float(v) for v in parts[1:]]).reshape(4, 4)
        except ValueError:
            raise RecordingError(f"{path}, line {no}: not a frame number and 16 numbers") from None
        if frame in poses:
            raise RecordingError(f"{path}, line {no}: frame {frame} appears twice")
        try:
            poses[frame] = _rigid(_matrix(values, f"{path}, line {no}"), f"{path}, line {no}")
        except RecordingError as exc:
            bad.append((frame, str(exc)))
    return poses, bad


def _id_of(item) -> int:
    """An actor entry's id for a skip record (-1 when it has no usable one)."""
    try:
        return int(item["id"])
    except (KeyError, TypeError, ValueError):
        return -1


def _state_common(item: dict, where: str) -> tuple[int, str, np.ndarray]:
    try:
        ident, kind = int(item["id"]), str(item["type"])
    except (KeyError, TypeError, ValueError):
        raise RecordingError(f"{where}: needs an integer id and a type") from None
    T = _rigid(_matrix(item.get("transform"), f"{where} (id {ident}): transform"), f"{where} (id {ident})")
    return ident, kind, T


def read_traffic(path) -> TrafficFrame:
    """``traffic_info/<frame>.yaml``: the ego (velocities), vehicles (transform, velocity, box)
    and pedestrians (transform, box extent, leg bones). An actor with a malformed or
    non-finite entry is left out and listed in ``skipped``; a file that is not such a mapping
    raises :class:`RecordingError`."""
    path = Path(path)
    data = _yaml(path)
    if not isinstance(data, dict) or "ego_vehicles" not in data:
        raise RecordingError(f"{path}: expected a mapping with ego_vehicles, vehicles and pedestrians")
    e = data["ego_vehicles"] or {}
    # the ego's motion as recorded; a malformed one is named (RecordingError), an absent one None
    vec = {k: None if e.get(k) is None else _vector(e[k], f"{path}: ego_vehicles.{k}")
           for k in ("velocity", "acceleration", "angular_velocity")}
    try:
        ego = EgoState(id=int(e["id"]), type=str(e["type"]), **vec)
    except (KeyError, TypeError, ValueError):
        raise RecordingError(f"{path}: ego_vehicles needs an id and a type") from None
    def vehicle(item, where: str, ident: int, kind: str, T: np.ndarray) -> VehicleState:
        box = item.get("bbox") or {}
        return VehicleState(
            id=ident, type=kind, transform=T, velocity=_vector(item.get("velocity"), f"{where}: velocity"),
            extent=_vector(box.get("extent"), f"{where}: bbox.extent"),
            bbox_transform=_rigid(_matrix(box.get("transform", np.eye(4).tolist()), f"{where}: bbox.transform"),
                                  f"{where}: bbox.transform"),
        )  # fmt: skip

    def pedestrian(item, where: str, ident: int, kind: str, T: np.ndarray) -> PedestrianState:
        bones = item.get("bones") or {}
        return PedestrianState(
            id=ident, type=kind, transform=T, extent=_vector(item.get("bbox_extent"), f"{where}: bbox_extent"),
            bones={b: _matrix(bones[b], f"{where}: bones.{b}") for b in BONES if b in bones},
        )  # fmt: skip

    found: dict[str, list] = {"vehicles": [], "pedestrians": []}
    skipped = []
    for key, build in (("vehicles", vehicle), ("pedestrians", pedestrian)):
        for k, item in enumerate(data.get(key) or []):
            where = f"{path}: {key}[{k}]"
            try:
                found[key].append(build(item, where, *_state_common(item, where)))
            except RecordingError as exc:
                skipped.append((_id_of(item), str(exc)))
    vehicles, pedestrians = found["vehicles"], found["pedestrians"]
    return TrafficFrame(ego=ego, vehicles=tuple(vehicles), pedestrians=tuple(pedestrians), skipped=tuple(skipped))


def read_actor_info(scene_dir) -> tuple[list[StaticActor], list[tuple[str, str]]]:
    """The static actors of ``SceneMeshes/<Town>_Opt/actor_info.json`` whose OBJ exists under
    ``bg_actors/``, and the ones left out ``(name, reason)`` (missing file, unknown class)."""
    scene_dir = Path(scene_dir)
    path = scene_dir / "actor_info.json"
    try:
        data = json.loads(path.read_text())
        actors = data["actors"]
    except FileNotFoundError:
        raise RecordingError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise RecordingError(f"{path}: not the export's actor list ({exc})") from None
    kept, skipped = [], []
    for k, a in enumerate(actors):
        name = str(a.get("name", f"actors[{k}]")) if isinstance(a, dict) else f"actors[{k}]"
        try:
            if "crosswalk" in name.lower():
                # the export's crosswalk decals: the authors leave them out of the occupancy too
                skipped.append((name, f"{path}: actor {name!r}: a crosswalk decal, left out"))
                continue
            label = str(a["semantic_label"])
            try:
                sem = by_name(label).id
            except KeyError:
                raise RecordingError(f"{path}: actor {name!r}: unknown class {label!r}") from None
            file = scene_dir / "bg_actors" / Path(str(a["exported_file"])).name
            if not file.is_file():
                raise RecordingError(f"{file}: missing mesh of actor {name!r}")
            kept.append(StaticActor(name=name, semantic_id=sem, instance_id=int(a.get("instance_id", 0)), file=file,
                                    bbox_min=_vector(a["bbox_min"], f"{path}: {name}.bbox_min"),
                                    bbox_max=_vector(a["bbox_max"], f"{path}: {name}.bbox_max")))  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            skipped.append((name, f"{path}: actor {name!r}: missing or bad field {exc}"))
        except RecordingError as exc:
            skipped.append((name, str(exc)))
    return kept, skipped


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """An exported OBJ in our frame: ``(N, 3)`` float64 vertices (metres, x forward, y left,
    z up: the mesh axes' ``(x, -z, y)``) and ``(M, 3)`` int64 triangles (winding kept: the axis
    change is a rotation)."""
    path = Path(path)
    try:
        obj = read_obj(str(path))
    except FileNotFoundError:
        raise RecordingError(f"{path}: missing mesh") from None
    except (OSError, ObjError) as exc:
        raise RecordingError(f"{path}: unreadable mesh ({exc})") from None
    faces = [f for g in obj.groups for f in g.faces]
    V = obj.vertices @ MESH_TO_WORLD.T
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(F):
        raise RecordingError(f"{path}: no triangles")
    if not np.isfinite(V).all():
        raise RecordingError(f"{path}: non-finite vertices")
    return V, F


def read_ply(path) -> dict[str, np.ndarray]:
    """An ASCII PLY of the saver (``lidar/`` or ``semantic_lidar/``): every property as a column,
    named as in the header. Points are in the sensor frame, right-handed (the saver negated y)."""
    path = Path(path)
    try:
        with path.open() as fh:
            head = []
            for line in fh:
                head.append(line.strip())
                if line.strip() == "end_header":
                    break
            body = fh.read()
    except FileNotFoundError:
        raise RecordingError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: unreadable ({exc})") from None
    if not head or head[0] != "ply" or "format ascii 1.0" not in head or head[-1] != "end_header":
        raise RecordingError(f"{path}: not an ASCII PLY (ply / format ascii 1.0 / ... / end_header)")
    names = [h.split()[-1] for h in head if h.startswith("property ")]
    try:
        count = next(int(h.split()[2]) for h in head if h.startswith("element vertex"))
    except (StopIteration, IndexError, ValueError):
        raise RecordingError(f"{path}: no 'element vertex <count>' line in the header") from None
    try:
        values = np.loadtxt(body.splitlines(), ndmin=2) if count else np.zeros((0, len(names)))
    except ValueError as exc:
        raise RecordingError(f"{path}: bad point rows ({exc})") from None
    if values.shape != (count, len(names)):
        raise RecordingError(f"{path}: header says {count} points of {len(names)} values, found {values.shape}")
    return {n: values[:, i] for i, n in enumerate(names)}


NOT_RECORDED = 255  # the semantic tag of a point of the plain scan (it carries none)


def read_scans(lidar_ply=None, semantic_ply=None) -> dict[str, np.ndarray]:
    """A frame's two recorded LiDAR scans as one set of points, in our LiDAR frame (x forward,
    y left, z up, metres: the saver's y-negated sensor frame is ours): CARLA's ``ray_cast`` scan
    (``lidar/<frame>.ply``: x, y, z, I) with ``scan`` 0 and its ``ray_cast_semantic`` scan
    (``semantic_lidar/<frame>.ply``: x, y, z, CosAngle, ObjIdx, ObjTag) with ``scan`` 1; a missing
    argument (None) gives no points. Columns x, y, z, distance, scan, intensity (NaN in scan 1),
    cos_angle (NaN in scan 0), object_index (-1 in scan 0), semantic (:data:`NOT_RECORDED` in scan 0).
    :class:`RecordingError` names a file without x, y, z, with non-finite points or a tag outside 0-254."""
    parts = []
    for scan, path, need in ((0, lidar_ply, ()), (1, semantic_ply, ("CosAngle", "ObjIdx", "ObjTag"))):
        if path is None:
            continue
        cols = read_ply(path)
        missing = [c for c in ("x", "y", "z", *need) if c not in cols]
        if missing:
            raise RecordingError(f"{path}: no property {', '.join(missing)} (the saver writes x y z "
                                 f"{'CosAngle ObjIdx ObjTag' if scan else 'I'})")  # fmt: skip
        xyz = np.column_stack([cols["x"], cols["y"], cols["z"]])
        if not np.isfinite(xyz).all():
            raise RecordingError(f"{path}: non-finite point coordinates")
        n = len(xyz)
        if scan:
            tag = cols["ObjTag"]
            if n and (tag.min() < 0 or tag.max() >= NOT_RECORDED or (tag != np.round(tag)).any()):
                raise RecordingError(f"{path}: ObjTag values outside the integer tags 0-254")
            extra = {"intensity": np.full(n, np.nan), "cos_angle": cols["CosAngle"],
                     "object_index": cols["ObjIdx"].astype(np.int64), "semantic": tag.astype(np.uint8)}
        else:
            extra = {"intensity": cols.get("I", np.full(n, np.nan)), "cos_angle": np.full(n, np.nan),
                     "object_index": np.full(n, -1, dtype=np.int64), "semantic": np.full(n, NOT_RECORDED, np.uint8)}
        parts.append({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "distance": np.linalg.norm(xyz, axis=1),
                      "scan": np.full(n, scan, dtype=np.uint8), **extra})
    names = ("x", "y", "z", "distance", "scan", "intensity", "cos_angle", "object_index", "semantic")
    if not parts:
        return {"x": np.zeros(0), "y": np.zeros(0), "z": np.zeros(0), "distance": np.zeros(0),
                "scan": np.zeros(0, np.uint8), "intensity": np.zeros(0), "cos_angle": np.zeros(0),
                "object_index": np.zeros(0, np.int64), "semantic": np.zeros(0, np.uint8)}  # fmt: skip
    return {c: np.concatenate([p[c] for p in parts]) for c in names}


# ------------------------------------------------------------------ maps


def decode_depth(png: np.ndarray) -> np.ndarray:
    """A uint16 depth PNG's metres (float32): ``value / 65535 * 80`` (80 m = nothing nearer)."""
    a = np.asarray(png)
    if a.dtype != np.uint16 or a.ndim != 2:
        raise RecordingError(f"depth map: expected a single-channel uint16 image, got {a.dtype} {a.shape}")
    return (a.astype(np.float32) / np.float32(65535.0)) * np.float32(DEPTH_RANGE)


def palette_lookup() -> dict[tuple[int, int, int], int]:
    """CARLA's CityScapes colour of every class id of the taxonomy (``utils/labels.py``)."""
    return {tuple(int(c) for c in by_id(i).color): i for i in range(30)}


def decode_semantics(rgb: np.ndarray) -> tuple[np.ndarray, int]:
    """Class ids (uint8, H x W) of a CityScapes-palette image and the number of pixels whose
    colour is in no class (they become 0, None)."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] < 3 or a.dtype != np.uint8:
        raise RecordingError(f"semantic map: expected an 8-bit RGB image, got {a.dtype} {a.shape}")
    key = (a[..., 0].astype(np.int64) << 16) | (a[..., 1].astype(np.int64) << 8) | a[..., 2]
    lut = palette_lookup()
    codes = np.array([(r << 16) | (g << 8) | b for r, g, b in lut], dtype=np.int64)
    ids = np.array(list(lut.values()), dtype=np.uint8)
    order = np.argsort(codes)
    pos = np.clip(np.searchsorted(codes[order], key), 0, len(codes) - 1)
    known = codes[order][pos] == key
    out = np.where(known, ids[order][pos], 0).astype(np.uint8)
    return out, int((~known).sum())
