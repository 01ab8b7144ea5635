"""The pure compute of the exports: our grids and boxes turned into what other datasets' files
hold (arrays in, arrays out, never a path).

* ``flow``  — flow in other datasets' units (UniOcc's voxels between ego grids)
* ``boxes`` — points in boxes, the part of a target grid our region covers
"""
