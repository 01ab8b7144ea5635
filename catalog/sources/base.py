"""The one interface every mesh source adapter implements.

An adapter lists a source root as :class:`SourceItem` s (one per source object: a file, a model
folder, a CSV row, a scene object...) and reads one item into a
:class:`~carlaocc.schemas.meshes.SourceAsset` (the contract ``carlaocc.stages.ingest.standardize`` accepts):
triangle parts in the SOURCE's own frame and units, with what the source declares about them (up and
forward axes, units, category, licence). Standardization (frame, units, cleaning, validation)
happens later, in ``carlaocc.stages.ingest.standardize``; adapters only read and describe.

A problem with one item raises :class:`SourceError` (reason + hint): the batch quarantines that
item and goes on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from carlaocc.schemas.meshes import SourceAsset


class SourceError(Exception):
    """An item that cannot be ingested: ``reason`` (short, for the quarantine table) and ``hint``."""

    def __init__(self, reason: str, hint: str = ""):
        super().__init__(reason)
        self.reason = reason
        self.hint = hint


@dataclass(frozen=True)
class SourceItem:
    """One thing to ingest. ``key`` is unique within the source and stable (a relative path, a
    model id, a sha256...); ``files`` are the absolute paths whose bytes define it (their
    fingerprints decide whether a re-run re-ingests it); ``meta`` is JSON-able adapter data."""

    key: str
    files: tuple[str, ...]
    meta: dict = field(default_factory=dict)


class SourceAdapter(Protocol):
    """What every adapter offers."""

    kind: str

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        """Every item under ``root``, sorted by key, except those inside a directory of
        ``exclude`` (absolute paths: a dataset root placed inside the source must not be read as
        source meshes). Raises SourceError when the root itself is unusable (missing, not the
        expected layout)."""
        ...

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        """Read one item; raises SourceError for a bad item."""
        ...
