"""Headless pictures, deterministic: the same inputs give byte-identical ``(H, W, 3)`` uint8 RGB
images (``carlaocc.catalog.images`` writes them). Views are pure numpy + numba (no GUI, no
OpenGL); words, axes, legends and colour scales are matplotlib's (Agg, no ``pyplot``), laid out
by :mod:`carlaocc.stages.render.layout`.

* :mod:`carlaocc.stages.render.raster` -- the one z-buffer triangle rasterizer every 3D view draws with
  (``fill_triangle``, a numba kernel), the camera axes, key light and Lambert constants.
* :mod:`carlaocc.stages.render.assets` -- ``render_asset``: shaded previews of an asset's mesh parts
  (orthographic, transparent parts blended, ground shadow); ``asset_sheet`` lays them out.
* :mod:`carlaocc.stages.render.layout` -- ``compose``: sheets of titled panels drawn pixel for pixel,
  metric axes on top views, a key per row (legend entries, colour scales) in matplotlib's font.
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
