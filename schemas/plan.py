"""A dataset root's plan: what ``carlaocc run`` last set out to build there -- the voxel sizes,
the slice (the first ``limit_frames`` frames, the sequences matching ``sequences``) and the
dataset config before the slice (taxonomy included). ``run``, ``status``, ``stage`` and
``export`` without options take it from the root (``catalog/plan.py`` reads and writes it as
``<root>/plan.yaml``); options change the keys they name, and a run remembers the result.

:func:`plan_changes` names the keys by which two plans differ, :func:`config_changes` those of
two configs (what ``run`` says when it replaces a plan and ``status`` says of a stage whose
config changed)."""

from __future__ import annotations

import fnmatch
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import voxel_size_key

DEFAULT_VOXEL_SIZES: tuple[float, ...] = (0.2,)


class PlanSlice(BaseModel):
    """The part of the plan that is built: the first ``limit_frames`` frames of every sequence
    (None: all of them) of the sequences matching any of ``sequences`` (fnmatch; empty: all)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    limit_frames: int | None = Field(None, ge=2)
    sequences: tuple[str, ...] = ()

    @field_validator("sequences")
    @classmethod
    def _all_is_empty(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        # '*' matches every sequence: the same slice as none, spelled one way
        return () if "*" in v else tuple(v)

    def matches(self, sequence_id: str) -> bool:
        return not self.sequences or any(fnmatch.fnmatchcase(sequence_id, p) for p in self.sequences)

    def describe(self, frame_count: int) -> str:
        """``"first 2 of 20 frames of sequences town00_*"``, ``"all 20 frames of every sequence"``."""
        frames = (f"first {min(self.limit_frames, frame_count)} of {frame_count} frames"
                  if self.limit_frames is not None and self.limit_frames < frame_count
                  else f"all {frame_count} frames")
        seqs = f"sequences {', '.join(self.sequences)}" if self.sequences else "every sequence"
        return f"{frames} of {seqs}"


class Plan(BaseModel):
    """A root's remembered plan (``<root>/plan.yaml``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    voxel_sizes: tuple[float, ...] = DEFAULT_VOXEL_SIZES
    slice: PlanSlice = PlanSlice()
    config: DatasetConfig = DatasetConfig()

    @field_validator("voxel_sizes")
    @classmethod
    def _some(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if not v or any(not (x > 0) for x in v):
            raise ValueError("voxel_sizes must list at least one positive voxel size in metres")
        return tuple(v)

    def effective_config(self) -> DatasetConfig:
        """The config the stages run on: :attr:`config` with the slice's frame limit applied
        (the same poses as the whole plan: only ``scenes.frame_count`` shrinks)."""
        if self.slice.limit_frames is None:
            return self.config
        scenes = self.config.scenes
        return self.config.model_copy(update={"scenes": scenes.model_copy(
            update={"frame_count": min(self.slice.limit_frames, scenes.frame_count)})})

    def summary(self) -> str:
        """One line: voxel sizes, slice, label table."""
        sizes = ", ".join(f"{voxel_size_key(v)} m" for v in self.voxel_sizes)
        return (f"{sizes}; {self.slice.describe(self.config.scenes.frame_count)}; "
                f"label table {self.config.taxonomy}")


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}, "c": [{"d": 2}]}`` -> ``{"a.b": 1, "c[0].d": 2}``: a nested JSON-like
    value as dotted keys to its leaves (an empty mapping or list is a leaf)."""
    if isinstance(data, dict) and data:
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(data, (list, tuple)) and data and any(isinstance(v, (dict, list, tuple)) for v in data):
        out = {}
        for i, v in enumerate(data):
            out.update(flatten(v, f"{prefix}[{i}]"))
        return out
    return {prefix: list(data) if isinstance(data, tuple) else data}


def _changes(old: dict[str, Any], new: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    a, b = flatten(old), flatten(new)
    # the old file's order, then keys only the new one has
    keys = list(a) + [k for k in b if k not in a]
    return [(k, a.get(k), b.get(k)) for k in keys if k not in a or k not in b or a[k] != b[k]]


def plan_changes(old: Plan, new: Plan) -> list[tuple[str, Any, Any]]:
    """``(key, old value, new value)`` for every leaf in which the plans differ, in the file's
    order (``slice.limit_frames``, ``config.scenes.frame_count``...; None for a key one lacks)."""
    return _changes(old.model_dump(mode="json"), new.model_dump(mode="json"))


def config_changes(old: BaseModel, new: BaseModel) -> list[str]:
    """The dotted keys in which two configs (of one model) differ."""
    return [k for k, _, _ in _changes(old.model_dump(mode="json"), new.model_dump(mode="json"))]


def describe_changes(changes: list[tuple[str, Any, Any]], limit: int = 6) -> str:
    """``"slice.limit_frames: 2 -> None, voxel_sizes: [0.2] -> [0.1]"`` (at most ``limit``, then
    how many more)."""
    def show(v: Any) -> str:
        return "(unset)" if v is None else str(v)

    parts = [f"{k}: {show(a)} -> {show(b)}" for k, a, b in changes[:limit]]
    more = len(changes) - limit
    return ", ".join(parts) + (f" and {more} more" if more > 0 else "")


__all__ = ["DEFAULT_VOXEL_SIZES", "Plan", "PlanSlice", "config_changes", "describe_changes", "flatten",
           "plan_changes"]
