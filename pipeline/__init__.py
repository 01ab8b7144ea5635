"""Orchestration: stage registry, Dask execution, incremental re-runs, the CLI."""
