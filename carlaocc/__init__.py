"""carlaocc: instance-centric panoptic occupancy datasets for autonomous driving, voxelized from
3D meshes.

The installed distribution is this one namespace:

* ``carlaocc.schemas``  — the contracts: pydantic records and configs, the grid spec, the
  taxonomy, and the in-memory types every layer shares. Nothing of ours imported.
* ``carlaocc.stages``   — pure compute, one sub-package per stage; arrays and records in and out,
  never a path.
* ``carlaocc.catalog``  — where data lives: store layout, Parquet/Zarr/GLB readers and writers,
  lineage, DuckDB views, external dataset formats and mesh sources.
* ``carlaocc.pipeline`` — orchestration: the stage engine (registry, runner), one wiring module
  per stage, the CLI.

This package is the small public Python API. Its names are imported on first use, so
``import carlaocc.stages.voxelize`` stays as light as the stage itself::

    import carlaocc
    store = carlaocc.Store("data")
    outcomes = carlaocc.run(store, carlaocc.DatasetConfig(), voxel_sizes=(0.2,))
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("carlaocc")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

# public name -> (module, attribute)
_API: dict[str, tuple[str, str]] = {
    "GridSpec": ("carlaocc.schemas.grid", "GridSpec"),
    "DatasetConfig": ("carlaocc.schemas.configs", "DatasetConfig"),
    "taxonomy": ("carlaocc.schemas", "taxonomy"),
    "Store": ("carlaocc.catalog.store", "Store"),
    "StoreError": ("carlaocc.catalog.store", "StoreError"),
    "OccupancyStore": ("carlaocc.catalog.occupancy", "OccupancyStore"),
    "SensorStore": ("carlaocc.catalog.sensors", "SensorStore"),
    "STAGES": ("carlaocc.pipeline.engine.registry", "STAGES"),
    "status": ("carlaocc.pipeline.engine.runner", "status"),
}

__all__ = ["__version__", "run", *_API]


def run(store, config=None, voxel_sizes=(0.2,), stages=None, scheduler=None, force=False):
    """Run the pipeline's stages (all by default, in dependency order) on ``store`` (a
    :class:`Store` or a root path/URL) at the given voxel sizes (metres); unchanged work is
    skipped. Returns one outcome per stage run. ``scheduler``: None for a LocalCluster,
    ``"synchronous"``, or a Dask scheduler address."""
    from carlaocc.catalog.store import Store
    from carlaocc.pipeline.engine.runner import run as run_stages
    from carlaocc.schemas.configs import DatasetConfig

    store = store if isinstance(store, Store) else Store(str(store))
    return run_stages(store, config or DatasetConfig(), tuple(float(v) for v in voxel_sizes), stages, scheduler, force)


def __getattr__(name: str):
    if name in _API:
        module, attr = _API[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'carlaocc' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
