"""Orchestration: the stage engine, one wiring module per stage, and the CLI.

* ``spec``          — what a stage is to the engine: ``StageSpec``, ``Partition``, ``Context``
* ``registry``      — the registered stages, in dependency order
* ``runner``        — planning (what is stale and why), Dask execution, lineage records
* ``code_version``  — a stage's code version, derived from what its wiring imports
* ``tasks``         — one module per stage: partitions, prepare, config and the task body
* ``cli``           — the ``carlaocc`` command line, one module per command group
* ``scene_editing`` — ``carlaocc scenes``: town and frame meshes, sequence swaps
* ``standalone``    — ``carlaocc voxelize`` of any mesh files
* ``export``        — ``carlaocc export`` to the layouts models train on
* ``audit``         — ``carlaocc audit``: quality scores of any dataset on disk
"""
