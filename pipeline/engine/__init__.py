"""The stage engine: what a stage is, which stages there are, and how a run plans, executes and
records them. It decides when a task runs, never what it writes, so it is left out of every
stage's code version; nothing here imports a command (``carlaocc.pipeline.cli`` or
``carlaocc.pipeline.commands``: tested by ``tests/test_layering.py``).

* ``spec``         — what a stage is to the engine: ``StageSpec``, ``Partition``, ``Context``,
  ``Prepared``, cache keys, the planning errors
* ``registry``     — the registered stages, in dependency order
* ``runner``       — planning (what is stale and why), status, lineage records, retiring orphans
* ``executors``    — where a partition's task runs: in-process, or Dask (a bounded window of
  submissions, LocalCluster sizing, ``--scheduler`` checks)
* ``code_version`` — a stage's code version, derived from what its wiring module imports
"""
