"""OpenDRIVE towns: a parsed network (:mod:`carlaocc.schemas.opendrive`) built into a town on the
contract of :mod:`carlaocc.stages.scenes.network`.

* ``geometry`` — OpenDRIVE geometry: reference lines, lane boundaries, surface meshes
* ``surfaces`` — an OpenDRIVE town's ground: lane surfaces, road marks, raster, terrain
* ``network``  — an OpenDRIVE town's lane graph and walk graph
* ``town``     — the driver (:func:`town.build_opendrive_town`), signals, buildings, vegetation
"""
