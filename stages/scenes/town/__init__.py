"""Procedural towns in three styles (``downtown``, ``suburb``, ``arterial``) on the town contract of
:mod:`carlaocc.stages.scenes.network`; :mod:`.build` documents the plan, the frame and the order of
construction.

* ``build``     — the driver: :func:`build.build_procedural_town`, town names, stuff classes
* ``layout``    — a procedural town's plan: styles, cross-sections, grid, the draft
* ``geometry``  — plan geometry: polylines, extruded slabs, polygon tests, footprints
* ``roads``     — carriageways, medians, road markings and the lane graph
* ``walkways``  — sidewalks, kerbs, block grounds and lots, outer ring, walk graph
* ``buildings`` — buildings in the lots and their frontages (fences, hedges, walls)
* ``furniture`` — junction control, lights and signs, street furniture, parked cars, trees
"""
