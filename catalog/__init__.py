"""Where data lives: the store layout, one place per format with load/save/exists, lineage, SQL.

* ``store``      — ``Store``: a dataset root (path or fsspec URL), layout, atomic writes, fingerprints
* ``parquet``    — Parquet tables of pydantic records (Arrow schemas from the models)
* ``zarrstore``  — ``FrameArrayStore``: frame-indexed Zarr v3 arrays, base of the two stores below
* ``occupancy``  — ``OccupancyStore``: occupancy.zarr/<seq>/<voxel size>/{semantic,instance,...}
* ``sensors``    — ``SensorStore`` (sensors.zarr camera maps) and ``LidarStore`` (lidar/ Parquet)
* ``zarrio``     — the low-level chunk codec and frame keys and fingerprints
* ``meshes``     — standardized meshes as GLB (``MeshStore``)
* ``panoptic``   — panoptic scene meshes as GLB (per-vertex class and instance)
* ``admesh``     — the ADMesh library's asset rows (duplicates once)
* ``lineage``    — the lineage log (catalog/runs)
* ``sql``        — read-only DuckDB views over every table
* ``usage``      — bytes and files per store part
* ``images``     — PNG encoding
* ``opendrive``  — the OpenDRIVE (.xodr) reader; ``towns`` — the built-in towns and their resolver
* ``bvh``        — the BVH motion-capture reader
* ``sources``    — external mesh sources (folder, ShapeNet, BuildingNet, MeshFleet, CARLA exports)
* ``formats``    — the occupancy layouts models train on (Occ3D, SemanticKITTI, SurroundOcc, CarlaOcc npz)
"""

from carlaocc.catalog.store import Store, StoreError

__all__ = ["Store", "StoreError"]
