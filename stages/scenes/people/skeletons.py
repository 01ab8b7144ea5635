"""The walkers' skeletons of a sequence: the ``skeletons`` table's rows (joints of the gait rig
as posed each frame, world and LiDAR frames)."""

from __future__ import annotations

from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import SkeletonRecord
from carlaocc.stages.geometry import invert_pose, pose_from_list, transform_points
from carlaocc.stages.scenes.people.pedestrians import JOINT_NAMES

__all__ = ["skeleton_rows"]


def skeleton_rows(actors, frames, rig_of) -> list:
    """The ``skeletons`` rows of a sequence: for every pedestrian actor (``Pedestrian`` class) in
    every frame, its :data:`JOINT_NAMES` joints as posed for the frame -- the rig's joints in the
    matched canonical phase (``phase_index``; the rest pose when None), moved by the actor's pose
    (asset -> world) into the world frame, then into the frame's LiDAR frame.

    ``actors`` ActorStateRecords and ``frames`` FrameRecords of one sequence; ``rig_of(asset_id)``
    the asset's :class:`~carlaocc.stages.scenes.people.pedestrians.PedestrianRig`. Rows are ordered by
    (frame, instance, joint)."""
    ped = taxonomy.by_name("Pedestrian").id
    to_lidar = {f.frame_index: invert_pose(pose_from_list(f.lidar_pose)) for f in frames}
    rows = []
    for a in sorted(actors, key=lambda a: (a.frame_index, a.instance_id)):
        if a.semantic_id != ped or a.frame_index not in to_lidar:
            continue
        # 1. the rig's joints in the frame's phase (asset frame), 2. into the world, 3. into the LiDAR frame
        J = rig_of(a.asset_id).joints(a.phase_index)
        world = transform_points(pose_from_list(a.pose), J)
        lidar = transform_points(to_lidar[a.frame_index], world)
        for j, name in enumerate(JOINT_NAMES):
            rows.append(SkeletonRecord(sequence_id=a.sequence_id, frame_index=a.frame_index, instance_id=a.instance_id,
                                       asset_id=a.asset_id, joint_index=j, joint=name,
                                       world=[float(v) for v in world[j]], lidar=[float(v) for v in lidar[j]]))
    return rows
