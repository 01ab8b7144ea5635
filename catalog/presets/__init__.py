"""Dataset plans shipped as config files (``carlaocc config --preset NAME``): ``paper`` is the
CarlaOcc paper's 104 sequences x 1,000 frames."""

from __future__ import annotations

import pathlib

__all__ = ["preset_names", "preset_path", "PAPER_LEVELS"]

_HERE = pathlib.Path(__file__).resolve().parent
PAPER_LEVELS = {"none": 1, "low": 3, "medium": 3, "high": 6}  # sequences per traffic level and town


def preset_names() -> list[str]:
    """The shipped presets, sorted (``["paper"]``)."""
    return sorted(p.stem for p in _HERE.glob("*.yaml"))


def preset_path(name: str) -> pathlib.Path:
    """The config file of preset ``name``; ValueError naming the presets for an unknown one."""
    path = _HERE / f"{name}.yaml"
    if pathlib.PurePath(name).name != name or not path.is_file():
        raise ValueError(f"unknown preset {name!r}; presets: {', '.join(preset_names())}")
    return path
