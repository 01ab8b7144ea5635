"""Headless pictures, pure numpy + numba (no GUI, no OpenGL, no plotting library), deterministic:
the same inputs give byte-identical ``(H, W, 3)`` uint8 RGB images (``carlaocc.catalog.images`` writes them).

* :mod:`carlaocc.stages.render.raster` -- the one z-buffer triangle rasterizer every 3D view draws with
  (``fill_triangle``, a numba kernel), the camera axes, key light and Lambert constants.
* :mod:`carlaocc.stages.render.assets` -- ``render_asset``: shaded previews of an asset's mesh parts
  (orthographic, transparent parts blended, ground shadow).
* :mod:`carlaocc.stages.render.sheets` -- the 5x7 bitmap font (``draw_text``) and labelled contact sheets.
* :mod:`carlaocc.stages.render.colours` -- colouring modes (instance, semantic, height) and the hashed
  colours of instance ids.
* :mod:`carlaocc.stages.render.occupancy` -- occupancy grids: bird's-eye height maps and 3D voxel views
  (numba column scans, pooling, surface voxels).
* :mod:`carlaocc.stages.render.figures` -- ``occupancy_figure`` and ``multi_voxel_size_figure``, composed
  of those views.
* :mod:`carlaocc.stages.render.sensors` -- camera maps (depth, normals, semantics, instances) and the
  rectification contact sheet ``sensor_sheet``.

Import from the modules (``from carlaocc.stages.render.assets import render_asset``): the package
itself imports none of them.
"""
