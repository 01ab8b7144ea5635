"""Recorded towns and sequences: a CARLA recording (read by
:mod:`carlaocc.catalog.carla_recording`) on the town contract and as scenes records, the way the
simulated ones are (:mod:`carlaocc.stages.scenes.traffic.simulation`). Pure compute on parsed objects.

World frame: the recording's right-handed world (x forward, y left, z up, metres), kept as is.

* **Town** (:func:`recorded_town`): every static actor's world-placed mesh becomes a town mesh
  ``"<town>/<actor name>"`` placed at the identity pose, stuff or thing by its class (things are
  numbered 1.. in actor order). No road network: the traffic is recorded, not simulated.
* **Frames**: the LiDAR pose per frame is the recording's; the ego is the LiDAR pose moved down
  by the rig's LiDAR mount; camera and LiDAR sensor poses follow from the rig (built from the
  recording's calibration by the caller). The ego's recorded velocity and acceleration (world
  frame) are kept as they are (``ego_states`` rows; a frame without them has none). Timestamps are the recorded frame numbers over the
  rate (10 Hz); frames are renumbered 0.. in order (a recording may skip frames).
* **Actors**: a stable instance id per CARLA actor id (numbered above the town's instances in id
  order). Vehicles: the blueprint's model (an ADMesh asset) placed at ``actor pose @ T(offset)``
  (``offset``: where standardization put the asset origin, in the actor frame), the recorded box
  (centre ``actor @ box``, size twice the half extents), yaw / pitch / roll of the actor's
  rotation, the recorded velocity (moved to the pose origin). Walkers: the walk-cycle frame
  matched from the gait signal (how far the left knee is ahead of the right, from the recorded
  lower-leg bones; :func:`match_walk_frames`), scaled to the recorded box's height
  (``scale`` = box height / the cycle's height, :func:`walker_scale`; the feet stay at the
  box's bottom, the head reaches its top) and placed at ``actor pose @ T(scale * offset - (0, 0,
  half height))``; box centred on the actor origin; velocity by central differences of its positions
  (the recording has none). Angular velocities from the angles' central differences
  (:func:`carlaocc.stages.geometry.angular_velocity`).
* **Skeletons**: the recorded lower-leg bones' origins (the knees: CARLA's ``crl_leg__L/R`` are
  socket transforms in the walker's actor frame), in the world and the LiDAR frame.

Not done: actors whose blueprint has no model are left out and counted (``skipped``); a walker's
proportions are the walk cycle's (one uniform scale: CARLA records no bone lengths but the legs').
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, FrameRecord, SensorPoseRecord, SequenceRecord,
                                      SkeletonRecord, EgoStateRecord)
from carlaocc.schemas.rig import RigConfig
from carlaocc.stages.geometry import (angular_velocity, box_center, invert_pose, is_watertight, pose_to_list,
                                      transform_points, yaw_pitch_roll)
from carlaocc.stages.scenes.network import RoadNetwork, Town
from carlaocc.stages.scenes.placing import Placer

__all__ = ["RecordedAsset", "WalkFrame", "RecordedFrame", "RecordedSequence", "recorded_town", "recorded_sequence",
           "traffic_level_of", "match_walk_frames", "translation", "cycle_height", "walker_scale"]  # fmt: skip


@dataclass(frozen=True)
class RecordedAsset:
    """An ADMesh asset standing for a recorded model and its origin in the actor frame (m)."""

    asset: AssetRecord
    offset: np.ndarray


@dataclass(frozen=True)
class WalkFrame:
    """One frame of the walk cycle: its asset, the asset origin in the actor frame with the feet
    at z = 0 (m; the actor's origin is then half the walker's height above them) and its gait
    signal: how far the left knee is ahead of the right one (any unit: the matcher normalizes)."""

    asset: AssetRecord
    offset: np.ndarray
    stride: float


@dataclass(frozen=True)
class RecordedFrame:
    """A recorded frame: its number, LiDAR-to-world pose and traffic (catalog objects)."""

    number: int
    lidar_pose: np.ndarray
    traffic: object  # catalog.carla_recording.TrafficFrame


@dataclass
class RecordedSequence:
    sequence: SequenceRecord
    frames: list[FrameRecord]
    sensor_poses: list[SensorPoseRecord]
    actors: list[ActorStateRecord]
    skeletons: list[SkeletonRecord]
    ego_states: list[EgoStateRecord] = field(default_factory=list)  # the frames whose ego motion is recorded
    skipped: list[tuple[int, int, str]] = field(default_factory=list)  # (frame, actor id, reason)
    phase_frames: dict[int, list[int]] = field(default_factory=dict)  # walker id -> matched walk frame per frame


def translation(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def traffic_level_of(index: int) -> str:
    """The CarlaOcc collection's traffic level of sequence ``index``: 00 none, 01-03 low, 04-06
    medium, 07 and above high."""
    return "none" if index == 0 else "low" if index <= 3 else "medium" if index <= 6 else "high"


def recorded_town(name: str, index: int, source: str, statics: Sequence[tuple[str, int, np.ndarray, np.ndarray]],
                  things: frozenset[int] | None = None) -> Town:
    """The town of a recording: ``statics`` = (actor name, class id, world vertices, faces);
    ``things`` (default: the default label table's) get instance ids."""
    placer = Placer(name) if things is None else Placer(name, things)
    stuff: dict[str, AssetGeometry] = {}
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for actor, sem, V, F in statics:
        key = f"{name}/{actor}"
        geom = AssetGeometry(asset_id=key, parts=(MeshPart(name=actor, vertices=V, faces=F, semantic_id=int(sem)),),
                             part_closed=(is_watertight(F),))  # fmt: skip
        stuff[key] = geom
        placer.add_stuff(geom)
        lo, hi = np.minimum(lo, V[:, :2].min(axis=0)), np.maximum(hi, V[:, :2].max(axis=0))
    if not stuff:
        raise ValueError(f"{source}: no static actor could be read: the town has no geometry")
    return Town(name=name, index=index, style="carla-recording", source=source, placements=placer.records,
                stuff=stuff, network=RoadNetwork(lanes=(), walkways=(), road_length=0.0),
                bounds=(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
                max_instance_id=placer.next_instance - 1)  # fmt: skip


LEFT, RIGHT = "crl_leg__L", "crl_leg__R"  # CARLA's lower-leg bones: their origins are the knees


WALK_WINDOW = 25  # recorded frames a gait fit looks at (the CarlaOcc authors' matching window)
WALK_HOP = 8  # frames between the centres of consecutive fits
GAIT_RATES = np.linspace(0.3, 3.0, 55)  # gait cycles per second tried (a slow stroll to a run)


def match_walk_frames(stride: np.ndarray, times: np.ndarray, cycle: Sequence[float]) -> np.ndarray:
    """The walk-cycle frame of each recorded frame of one walker. ``stride`` (T,) is how far its
    left knee is ahead of the right one (m, from the recorded bones) at ``times`` (T,) s;
    ``cycle`` (K,) the same signal over the walk cycle's frames (any unit, any scale).

    The CarlaOcc authors match this one-dimensional gait signal over a 25-frame window; here, over
    windows of :data:`WALK_WINDOW` frames every :data:`WALK_HOP` frames, the phase at the window's
    centre and the gait rate (cycles/s, :data:`GAIT_RATES`) are chosen so the cycle's signal,
    linearly interpolated at the implied phases and scaled by its least-squares gain (>= 0),
    best fits the recorded one; the frames near the centre take the phase the fit gives them.
    The value alone could not tell a leg swinging forward from one swinging back; the fit over
    time can."""
    r = np.asarray(stride, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    c = np.asarray(cycle, dtype=np.float64)
    K, T = len(c), len(r)
    out = np.zeros(T, dtype=np.int64)
    if K == 0 or T == 0:
        return out
    phases = np.arange(4 * K) / (4 * K)  # candidate phases at the window centre

    def signal(ph: np.ndarray) -> np.ndarray:
        # the cycle's signal at fractional phases (circular linear interpolation)
        x = np.mod(ph, 1.0) * K
        i = np.floor(x).astype(np.int64) % K
        w = x - np.floor(x)
        return c[i] * (1.0 - w) + c[(i + 1) % K] * w

    for centre in range(0, T, WALK_HOP):
        lo, hi = max(0, centre - WALK_WINDOW // 2), min(T, centre + WALK_WINDOW // 2 + 1)
        dt = t[lo:hi] - t[centre]
        # 1. the cycle's signal for every (phase, rate) over the window: (P, R, W)
        pred = signal(phases[:, None, None] + GAIT_RATES[None, :, None] * dt[None, None, :])
        # 2. the least-squares gain (>= 0) and the residual of each candidate
        obs = r[lo:hi]
        gain = np.maximum(np.einsum("prw,w->pr", pred, obs) / np.maximum(np.einsum("prw,prw->pr", pred, pred), 1e-12), 0)
        err = np.einsum("prw,prw->pr", obs - gain[..., None] * pred, obs - gain[..., None] * pred)
        p, q = np.unravel_index(int(np.argmin(err)), err.shape)
        # 3. the frames nearest this centre take the fitted phase, as cycle frames
        a, b = max(0, centre - WALK_HOP // 2), min(T, centre + (WALK_HOP + 1) // 2) if centre + WALK_HOP < T else T
        ph = phases[p] + GAIT_RATES[q] * (t[a:b] - t[centre])
        out[a:b] = np.rint(np.mod(ph, 1.0) * K).astype(np.int64) % K
    return out


SCALE_DECIMALS = 4  # walker scales are rounded to this many decimals (a cycle as tall as the box: exactly 1)


def cycle_height(cycle: Sequence[WalkFrame]) -> float:
    """The walk cycle's height (m): the highest top of its frames above the feet (the frames'
    origins in the actor frame with the feet at z = 0, plus their assets' heights)."""
    return max(float(w.offset[2]) + float(w.asset.extent[2]) for w in cycle)


def walker_scale(height: float, cycle: Sequence[WalkFrame]) -> float:
    """The uniform scale that makes the walk cycle ``height`` metres tall (a recorded walker's box
    height), rounded to :data:`SCALE_DECIMALS` decimals."""
    return round(height / cycle_height(cycle), SCALE_DECIMALS)


def _at(velocity: np.ndarray, omega: np.ndarray, actor: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The velocity of the pose origin (flow turns a body about it) from the actor origin's:
    ``v + omega x (p_pose - p_actor)``."""
    return np.asarray(velocity, dtype=np.float64) + np.cross(omega, pose[:3, 3] - actor[:3, 3])


def recorded_sequence(sequence_id: str, town: Town, index: int, frames: Sequence[RecordedFrame], rig: RigConfig,
                      models: Mapping[str, RecordedAsset], cycle: Sequence[WalkFrame], ego_asset_id: str = "",
                      rate_hz: float = 10.0) -> RecordedSequence:  # fmt: skip
    """The scenes records of one recorded sequence (see the module docstring). ``models`` maps
    each vehicle type (blueprint id) of the traffic to its asset; ``ego_asset_id`` is the ego's."""
    if not frames:
        raise ValueError(f"{sequence_id}: no frame has a LiDAR pose and traffic")
    lidar_to_ego = np.asarray(rig.lidar.sensor_to_ego(), dtype=np.float64)
    ego_from_lidar = invert_pose(lidar_to_ego)
    cams = [(c.name, np.asarray(c.camera_to_ego(), dtype=np.float64)) for c in rig.cameras]
    # 1. stable instance ids: every actor id of the sequence, in id order, above the town's
    ids = sorted({a.id for f in frames for a in (*f.traffic.vehicles, *f.traffic.pedestrians)})
    instance = {aid: town.max_instance_id + 1 + k for k, aid in enumerate(ids)}
    out = RecordedSequence(
        sequence=SequenceRecord(sequence_id=sequence_id, town=town.name, seed=0, frame_count=len(frames),
                                rate_hz=rate_hz, traffic_level=traffic_level_of(index), ego_asset_id=ego_asset_id),
        frames=[], sensor_poses=[], actors=[], skeletons=[])  # fmt: skip
    # 2. per actor: its poses over the frames (for velocities and angle rates)
    tracks: dict[int, list[tuple[int, np.ndarray]]] = {}
    for k, f in enumerate(frames):
        for a in (*f.traffic.vehicles, *f.traffic.pedestrians):
            tracks.setdefault(a.id, []).append((k, a.transform))
    times = np.array([f.number / rate_hz for f in frames])
    rates: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for aid, track in tracks.items():
        ks = np.array([k for k, _ in track])
        pos = np.array([T[:3, 3] for _, T in track])
        ang = np.unwrap(np.array([yaw_pitch_roll(T) for _, T in track]), axis=0)
        if len(ks) >= 2:
            vel = np.gradient(pos, times[ks], axis=0)
            dang = np.gradient(ang, times[ks], axis=0)
        else:
            vel, dang = np.zeros_like(pos), np.zeros_like(ang)
        omega = angular_velocity(ang[:, 0], ang[:, 1], ang[:, 2], dang[:, 0], dang[:, 1], dang[:, 2])
        for j, k in enumerate(ks):
            rates[(aid, int(k))] = (vel[j], omega[j])
    # the walk-cycle frame of every walker frame, matched over the walker's whole track
    phase: dict[tuple[int, int], int] = {}
    if cycle:
        signal = np.array([w.stride for w in cycle])
        strides: dict[int, list[tuple[int, float]]] = {}
        for k, f in enumerate(frames):
            for p in f.traffic.pedestrians:
                if LEFT in p.bones and RIGHT in p.bones:
                    strides.setdefault(p.id, []).append((k, float(p.bones[LEFT][0, 3] - p.bones[RIGHT][0, 3])))
                else:
                    phase[(p.id, k)] = 0
        for aid, track in strides.items():
            ks = [k for k, _ in track]
            for k, j in zip(ks, match_walk_frames(np.array([d for _, d in track]), times[ks], signal)):
                phase[(aid, k)] = int(j)
    # 3. records, frame by frame
    for k, f in enumerate(frames):
        lidar = np.asarray(f.lidar_pose, dtype=np.float64)
        ego = lidar @ ego_from_lidar
        world_to_lidar = invert_pose(lidar)
        out.frames.append(FrameRecord(sequence_id=sequence_id, frame_index=k, timestamp=float(times[k]),
                                      ego_pose=pose_to_list(ego), lidar_pose=pose_to_list(lidar)))  # fmt: skip
        e = f.traffic.ego
        if e.velocity is not None and e.acceleration is not None:  # the recording's own values, kept
            out.ego_states.append(EgoStateRecord(sequence_id=sequence_id, frame_index=k,
                                                 velocity=[float(c) for c in e.velocity],
                                                 acceleration=[float(c) for c in e.acceleration]))  # fmt: skip
        for name, T in cams:
            out.sensor_poses.append(SensorPoseRecord(sequence_id=sequence_id, frame_index=k, sensor=name,
                                                     pose=pose_to_list(ego @ T)))  # fmt: skip
        out.sensor_poses.append(SensorPoseRecord(sequence_id=sequence_id, frame_index=k, sensor=rig.lidar.name,
                                                 pose=pose_to_list(lidar)))  # fmt: skip
        rows = []
        for v in f.traffic.vehicles:
            model = models.get(v.type)
            if model is None:
                out.skipped.append((f.number, v.id, f"no model for blueprint {v.type!r}"))
                continue
            pose = v.transform @ translation(*model.offset)
            box = v.transform @ v.bbox_transform
            yaw, pitch, roll = yaw_pitch_roll(v.transform)
            rows.append(ActorStateRecord(
                sequence_id=sequence_id, frame_index=k, instance_id=instance[v.id], asset_id=model.asset.asset_id,
                semantic_id=model.asset.category_id, pose=pose_to_list(pose),
                box_center=[float(c) for c in box[:3, 3]], box_size=[float(2 * e) for e in v.extent],
                yaw=yaw, pitch=pitch, roll=roll,
                velocity=[float(c) for c in _at(v.velocity, rates[(v.id, k)][1], v.transform, pose)],
                angular_velocity=[float(c) for c in rates[(v.id, k)][1]],
            ))  # fmt: skip
        for p in f.traffic.pedestrians:
            if not cycle:
                out.skipped.append((f.number, p.id, "no walk cycle to pose the walker with"))
                continue
            if not p.extent[2] > 0:
                out.skipped.append((f.number, p.id, f"box height {2 * p.extent[2]:g} m: cannot scale the walker to it"))
                continue
            j = int(phase[(p.id, k)])
            out.phase_frames.setdefault(p.id, []).append(j)
            # the walk cycle scaled about the feet to the recorded box's height (CARLA's walker
            # box stands on the feet); the asset's axes are the actor's: its origin sits at the
            # scaled offset, the feet a half height below the actor origin
            scale = walker_scale(2 * float(p.extent[2]), cycle)
            off = cycle[j].offset * scale
            pose = p.transform @ translation(off[0], off[1], off[2] - p.extent[2])
            yaw, pitch, roll = yaw_pitch_roll(p.transform)
            vel, omega = rates[(p.id, k)]
            rows.append(ActorStateRecord(
                sequence_id=sequence_id, frame_index=k, instance_id=instance[p.id], asset_id=cycle[j].asset.asset_id,
                semantic_id=cycle[j].asset.category_id, pose=pose_to_list(pose),
                box_center=[float(c) for c in p.transform[:3, 3]], box_size=[float(2 * e) for e in p.extent],
                yaw=yaw, pitch=pitch, roll=roll, velocity=[float(c) for c in _at(vel, omega, p.transform, pose)],
                angular_velocity=[float(c) for c in omega], gait_phase=j / len(cycle), scale=scale,
            ))  # fmt: skip
            # the recorded bones: socket transforms in the actor frame; their origins the knees
            for b, name in enumerate(sorted(p.bones)):
                world = transform_points(p.transform, p.bones[name][None, :3, 3])[0]
                out.skeletons.append(SkeletonRecord(
                    sequence_id=sequence_id, frame_index=k, instance_id=instance[p.id], asset_id=cycle[j].asset.asset_id,
                    joint_index=b, joint=name, world=[float(c) for c in world],
                    lidar=[float(c) for c in transform_points(world_to_lidar, world[None])[0]],
                ))  # fmt: skip
        for aid, reason in f.traffic.skipped:
            out.skipped.append((f.number, aid, reason))
        out.actors.extend(sorted(rows, key=lambda r: r.instance_id))
    return out
