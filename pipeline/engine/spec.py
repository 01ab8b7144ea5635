"""What a stage is to the engine: its spec, its partitions and the context partitioning sees.

A stage is a frozen config (a section of :class:`~carlaocc.schemas.configs.DatasetConfig`), a
task function that wires catalog readers -> pure ``carlaocc.stages`` compute -> catalog writers
for one partition, and the partitions it runs over. Each stage's spec lives in its wiring module,
``carlaocc.pipeline.tasks.<stage>``; :mod:`carlaocc.pipeline.engine.registry` lists them. A stage's code
version is derived from what its wiring module imports (:mod:`carlaocc.pipeline.engine.code_version`),
so editing the code a stage runs re-runs it, and editing anything else does not.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any, Callable

from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.code_version import code_version
from carlaocc.schemas.configs import DatasetConfig, StageConfig


@dataclass(frozen=True)
class Partition:
    """One task of a stage: a key unique within the stage, JSON-able params, and the upstream
    (stage, partition key) pairs whose outputs it reads."""

    key: str
    params: dict[str, Any] = field(default_factory=dict)
    needs: tuple[tuple[str, str], ...] = ()
    files: tuple[str, ...] = ()  # external input files, fingerprinted by their bytes


@dataclass(frozen=True)
class Context:
    """What partitioning a stage may look at: the store, the config, the requested voxel
    sizes (metres) and the sequence selection (``fnmatch`` patterns on sequence ids; empty:
    every sequence)."""

    store: Store
    config: DatasetConfig
    voxel_sizes: tuple[float, ...]
    sequence_patterns: tuple[str, ...] = ()


@dataclass(frozen=True)
class Prepared:
    """What a stage's ``prepare`` did: ``invalid``, the keys of partitions planned as done that
    its creations invalidated (they run as well); ``removed``, the store-relative outputs it
    deleted because no partition owns them any more (the runner retires the lineage records of
    partitions no longer planned that recorded any of them: never planned, never verified)."""

    invalid: frozenset[str] = frozenset()
    removed: frozenset[str] = frozenset()


class PlanError(Exception):
    """The requested run cannot be planned (unknown stage, upstream never run...): exit code 2."""


class SelectionError(ValueError):
    """A sequence selection (``--sequences``) that matches no sequence of the dataset."""


class UpstreamMissing(Exception):
    """A stage cannot be partitioned yet because an upstream stage has not produced its outputs."""


@dataclass(frozen=True)
class StageSpec:
    name: str
    description: str
    upstream: tuple[str, ...]
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    partitions: Callable[[Context], list[Partition]]
    task: Callable[[Store, StageConfig, Partition], dict[str, str]]
    # creates outputs before tasks run (e.g. Zarr arrays) or removes those no partition owns any
    # more; given the partitions to run and all partitions, returns the keys of partitions its
    # creation invalidated (to run as well), or a Prepared that also names what it removed
    prepare: Callable[[Context, list[Partition], list[Partition]], set[str] | Prepared] | None = None
    # the stage's config: by default the DatasetConfig section of the stage's name
    config_of: Callable[[DatasetConfig], StageConfig] | None = None

    def config(self, config: DatasetConfig) -> StageConfig:
        return self.config_of(config) if self.config_of else getattr(config, self.name)

    def config_hash(self, config: DatasetConfig) -> str:
        payload = json.dumps(self.config(config).model_dump(mode="json"), sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]

    def code_version(self) -> str:
        """Hash of the code the stage's task runs: its module and what that imports."""
        return code_version(self.task.__module__)


def cache_key(stage: str, code_version: str, config_hash: str, partition: Partition,
              input_fingerprints: dict[str, str]) -> str:
    """hash(stage, code version, config hash, partition, input fingerprints)."""
    payload = json.dumps(
        [stage, code_version, config_hash, partition.key, partition.params, input_fingerprints],
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:24]
