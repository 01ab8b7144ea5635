"""Ingestion stage: sources of ADMesh assets (the built-in procedural source)."""

from carlaocc.stages.ingest.procedural import IngestResult, asset_id_for, ingest_procedural

__all__ = ["IngestResult", "asset_id_for", "ingest_procedural"]
