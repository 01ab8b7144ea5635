"""Where data lives: the store layout, Parquet/Zarr/GLB readers and writers, lineage, SQL views."""

from carlaocc.catalog.store import Store, StoreError

__all__ = ["Store", "StoreError"]
