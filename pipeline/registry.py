"""The stage registry: what each stage is, what it reads and writes, how it is partitioned.

A stage is a frozen config (a field of :class:`schemas.configs.DatasetConfig`), a task function
that wires catalog readers -> pure ``stages`` compute -> catalog writers for one partition, and
the partitions it runs over. Its code version is a hash of the source of its compute package and
its task function, so editing either re-runs it.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import pkgutil
from dataclasses import dataclass, field
from typing import Any, Callable

from carlaocc.catalog.store import Store
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
    """What partitioning a stage may look at: the store, the config and the requested resolutions."""

    store: Store
    config: DatasetConfig
    resolutions: tuple[float, ...]


class UpstreamMissing(Exception):
    """A stage cannot be partitioned yet because an upstream stage has not produced its outputs."""


@dataclass(frozen=True)
class StageSpec:
    name: str
    description: str
    upstream: tuple[str, ...]
    code_modules: tuple[str, ...]
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    partitions: Callable[[Context], list[Partition]]
    task: Callable[[Store, StageConfig, Partition], dict[str, str]]
    # creates outputs before tasks run (e.g. Zarr arrays); given the partitions to run and all
    # partitions, returns the keys of partitions its creation invalidated (to run as well)
    prepare: Callable[[Context, list[Partition], list[Partition]], set[str]] | None = None
    # the stage's config: by default the DatasetConfig section of the stage's name
    config_of: Callable[[DatasetConfig], StageConfig] | None = None

    def config(self, config: DatasetConfig) -> StageConfig:
        return self.config_of(config) if self.config_of else getattr(config, self.name)

    def config_hash(self, config: DatasetConfig) -> str:
        payload = json.dumps(self.config(config).model_dump(mode="json"), sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]

    def code_version(self) -> str:
        return _code_version(self.code_modules, self.task)


_CODE_VERSIONS: dict[tuple, str] = {}


def _code_version(modules: tuple[str, ...], task: Callable) -> str:
    key = (modules, task)
    if key not in _CODE_VERSIONS:
        h = hashlib.sha256()
        for name in modules:
            mod = importlib.import_module(name)
            files = [inspect.getsourcefile(mod)]
            if hasattr(mod, "__path__"):  # a package: every module in it
                for info in sorted(pkgutil.walk_packages(mod.__path__, name + "."), key=lambda i: i.name):
                    files.append(inspect.getsourcefile(importlib.import_module(info.name)))
            for f in files:
                with open(f, "rb") as fh:
                    h.update(fh.read())
        h.update(inspect.getsource(task).encode())
        _CODE_VERSIONS[key] = h.hexdigest()[:16]
    return _CODE_VERSIONS[key]


def cache_key(stage: str, code_version: str, config_hash: str, partition: Partition,
              input_fingerprints: dict[str, str]) -> str:
    """hash(stage, code version, config hash, partition, input fingerprints)."""
    payload = json.dumps(
        [stage, code_version, config_hash, partition.key, partition.params, input_fingerprints],
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:24]
