"""The pure compute of the exports: resampling our volumes onto other datasets' grids and label
sets (Occ3D-nuScenes, SSCBench-KITTI-360), their instance ids and flow, the coarse SSC targets.
Arrays in, arrays out; the exporters that read the store and write the files are
``carlaocc.pipeline.export*``.

* ``resample`` — :class:`resample.TargetGrid` and the published grids, :func:`resample.resample`,
  :func:`resample.resample_panoptic`, :func:`resample.downsample_ssc`
"""
