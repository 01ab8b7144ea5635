"""The contracts every layer shares. Nothing of ours is imported here and nothing is read or
written; numpy is the only array library.

* ``configs``   — the frozen pydantic stage configs and ``DatasetConfig`` (the ``--config`` file)
* ``grid``      — ``GridSpec``: region, voxel size, shape and origin of an occupancy grid
* ``records``   — the pydantic row models of every Parquet table (assets, placements, frames...)
* ``rig``       — the ego rig: six cameras and the 32-beam LiDAR, their mounts and intrinsics
* ``taxonomy``  — the 30 CARLA classes, sub-classes and mappings to other label sets (one table)
* ``meshes``    — in-memory mesh contracts: SourcePart/SourceAsset (source side), MeshPart,
  AssetGeometry, SceneMesh, Axis, Units
* ``opendrive`` — OpenDRIVE road-network records (a parsed ``.xodr``)
* ``motion``    — skeleton motion clips (``MotionClip``, e.g. a BVH walk)
"""
