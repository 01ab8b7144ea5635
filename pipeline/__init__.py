"""Orchestration, in three parts; the engine and the wiring import no command (tested):

* ``engine``   — the stage engine: spec, registry, runner (planning, status, lineage),
  executors (where tasks run), code versions
* ``tasks``    — the stages' wiring, one module per stage: partitions, prepare, config and the
  task body (catalog readers -> ``carlaocc.stages`` compute -> catalog writers)
* ``cli``      — the ``carlaocc`` command line, one module per command group
* ``commands`` — what the commands call beyond running stages: ``export`` (a package, one
  module per format family), ``audit``, ``standalone`` (``carlaocc voxelize``),
  ``scene_editing`` (``carlaocc scenes``), ``verify``
"""
