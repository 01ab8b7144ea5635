"""The simulator artifact model: which meshes of a frame a UE5 CARLA semantic pass leaves
unlabelled (see :class:`carlaocc.schemas.configs.SimulatorArtifacts`).

An asset is unlabelled when its class is listed in ``unlabelled_classes`` (all its meshes, stuff
included), or when it is a thing whose stable hash falls below ``unlabelled_fraction``: the
first 8 bytes of ``sha256(f"{seed}:{asset_id}")`` read as a fraction of 2**64. The same asset is
thus unlabelled in every frame and sequence, as a non-Nanite asset is for a real renderer.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import SimulatorArtifacts
from carlaocc.schemas.meshes import SceneMesh


def asset_fraction(asset_id: str, seed: int) -> float:
    """A stable pseudo-random number in [0, 1) per (seed, asset id)."""
    h = hashlib.sha256(f"{seed}:{asset_id}".encode()).digest()
    return int.from_bytes(h[:8], "big") / 2.0**64


def unlabelled_meshes(scene: Sequence[SceneMesh], model: SimulatorArtifacts) -> np.ndarray:
    """Bool per scene mesh: whether the semantic pass leaves it unlabelled (0)."""
    classes = {taxonomy.by_name(n).id for n in model.unlabelled_classes}
    memo: dict[str, bool] = {}
    out = np.zeros(len(scene), dtype=bool)
    for i, m in enumerate(scene):
        if m.semantic_id in classes:
            out[i] = True
        elif not m.is_stuff and model.unlabelled_fraction > 0 and m.asset_id:
            if m.asset_id not in memo:
                memo[m.asset_id] = asset_fraction(m.asset_id, model.seed) < model.unlabelled_fraction
            out[i] = memo[m.asset_id]
    return out
