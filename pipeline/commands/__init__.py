"""What the ``carlaocc`` commands call beyond running stages; each reads and writes through the
catalog and computes with ``carlaocc.stages``, like a stage's wiring, but outside the engine.

* ``export``        — ``carlaocc export``: a registry of formats, one module per format family
* ``audit``         — ``carlaocc audit``: quality scores of any dataset on disk
* ``standalone``    — ``carlaocc voxelize`` of any mesh files or ADMesh assets
* ``scene_editing`` — ``carlaocc scenes``: town and frame meshes, sequence swaps
* ``verify``        — ``carlaocc verify``: re-hash recorded outputs
"""
