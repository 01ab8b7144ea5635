"""The pure compute of the exports: our grids, flow and boxes turned into what other datasets'
files hold (arrays in, arrays out, never a path); the commands that read the store and write the
files are ``carlaocc.pipeline.commands.export``.

* ``resample`` — :class:`resample.TargetGrid` and the published grids (Occ3D-nuScenes,
  SSCBench-KITTI-360, SemanticKITTI, SurroundOcc, OpenOcc v2, UniOcc), :func:`resample.resample`,
  :func:`resample.resample_panoptic`, :func:`resample.downsample_ssc`
* ``flow``     — flow in other datasets' units (UniOcc's voxels between ego grids)
* ``boxes``    — points in boxes, the part of a target grid our region covers
"""
