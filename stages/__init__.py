"""Pure compute, one sub-package per stage: arrays, meshes and records in, arrays and records
out. Nothing here opens a path or imports the catalog or the pipeline.

* ``ingest``     — the procedural ADMesh library; standardization of source meshes
* ``scenes``     — towns, traffic, pedestrians, per-frame panoptic scene assembly
* ``voxelize``   — exact triangle-box voxelization, fill, composition, flow, visibility masks, pooling
* ``export``     — the exports' pure compute: resampling onto other datasets' grids and label sets
* ``sensors``    — ray-cast camera maps and LiDAR, simulator artifacts, rectification, normals
* ``quality``    — dataset-quality scores: spatial continuity, temporal consistency
* ``report``     — dataset statistics and the report's plots
* ``evaluation`` — the benchmark metrics: SSC IoU/mIoU, panoptic PQ/SQ/RQ, depth, detection
* ``render``     — headless pictures of assets, occupancy frames and camera maps
* ``geometry``   — poses, transforms and mesh measures shared by every stage
* ``threads``, ``scratch`` — kernel thread caps; per-thread reusable buffers
"""
