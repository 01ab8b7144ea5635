"""What the report stage computes and draws, from counts and records (no file is read here).

* ``statistics`` — voxels and distinct instances per class (numba counting kernels, streamed per
  sequence), the ADMesh asset distribution, the static/dynamic share, totals per voxel size
* ``plots``      — the report's matplotlib figures as PNG bytes (class voxels, instances,
  static/dynamic share, assets, quality scores)
"""
