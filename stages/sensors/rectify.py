"""Instance-guided rectification of sensor artifacts (paper, appendix "Sensor Artifacts
Rectification"), on arrays only: whatever produced the raw maps.

Given a frame's scene meshes, the **compact mesh** M holds only the parts a simulator gets wrong:
translucent parts and the meshes of assets its semantic pass leaves unlabelled
(:func:`compact_mesh`). Ray casting M gives ``D_rc``, ``S_rc``, ``I_rc``. Then, per pixel
(:func:`rectify`):

1. ``D = min(D_raw, D_rc)`` (0, "no surface", counts as +inf on both sides);
2. transparency region ``Omega_t = D_raw - D >= epsilon`` (a raw pixel with no surface behind a
   glass hit counts as infinitely far, so it is in Omega_t);
3. omission region ``Omega_s = S_raw == 0`` (the empty label);
4. in ``Omega_t | Omega_s`` the semantic and instance labels are the ray-cast ones, elsewhere the
   raw ones. One refinement of the paper's formula: an omission pixel where M has no surface keeps
   its raw (empty) label, since there is no ray-cast label to give it.

Every pixel outside the error region whose ray-cast depth is not nearer than the raw one comes
out byte-identical to the raw maps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.meshes import SceneMesh
from carlaocc.stages.scenes.assembly import PanopticMesh, flatten
from carlaocc.stages.sensors.raycast import UNLABELLED, CameraMaps


@dataclass(frozen=True)
class Rectification:
    """Rectified maps of one image and the regions that were repaired (bool (H, W) each)."""

    maps: CameraMaps
    transparency: np.ndarray  # Omega_t: raw depth >= epsilon behind the rectified depth
    omission: np.ndarray  # Omega_s: raw label empty
    depth_changed: np.ndarray  # D differs from D_raw (includes glass closer than epsilon to what is behind)

    @property
    def error_region(self) -> np.ndarray:
        """Omega_err = Omega_t | Omega_s: where the ray-cast labels replaced the raw ones (or would
        have, for omission pixels M does not cover)."""
        return self.transparency | self.omission


def compact_mesh(scene: Sequence[SceneMesh], unlabelled: np.ndarray) -> PanopticMesh:
    """The paper's M: the transparent meshes of ``scene`` and those flagged in ``unlabelled``
    (bool per scene mesh), flattened with their true labels (scene frame, metres)."""
    flags = np.asarray(unlabelled, dtype=bool).reshape(-1)
    if len(flags) != len(scene):
        raise ValueError(f"unlabelled has {len(flags)} flags for {len(scene)} scene meshes")
    return flatten([m for m, u in zip(scene, flags) if m.transparent or u])


def rectify(raw: CameraMaps, cast: CameraMaps, epsilon: float) -> Rectification:
    """Rectify one image's raw maps with the maps ray-cast from the compact mesh (same camera,
    same conventions: depth float32 m with 0 = no surface). ``raw.instance`` may be None (a
    recorder without an instance camera): the rectified instance map is then None too."""
    if epsilon <= 0 or not np.isfinite(epsilon):
        raise ValueError(f"epsilon must be a positive number of metres, got {epsilon}")
    if raw.depth.shape != cast.depth.shape or raw.semantic.shape != raw.depth.shape:
        raise ValueError(f"raw maps {raw.depth.shape}/{raw.semantic.shape} and ray-cast maps "
                         f"{cast.depth.shape} differ in size")
    # 1. depth: 0 (no surface) as +inf, pointwise minimum, back to 0
    d_raw = np.where(raw.depth > 0, raw.depth, np.float32(np.inf)).astype(np.float32)
    d_rc = np.where(cast.depth > 0, cast.depth, np.float32(np.inf)).astype(np.float32)
    d = np.minimum(d_raw, d_rc)
    depth = np.where(np.isfinite(d), d, np.float32(0)).astype(np.float32)
    # 2. transparency: raw depth at least epsilon behind (inf - finite = inf; inf - inf = nan: no)
    with np.errstate(invalid="ignore"):
        transparency = (d_raw - d) >= np.float32(epsilon)
    # 3. omission: the empty label
    omission = raw.semantic == UNLABELLED
    # 4. labels: ray-cast in the error region where M has a surface, raw elsewhere
    take = (transparency | omission) & (cast.depth > 0)
    semantic = np.where(take, cast.semantic, raw.semantic).astype(np.uint8)
    instance = None
    if raw.instance is not None:
        instance = np.where(take, cast.instance, raw.instance).astype(np.uint32)
    # keep the raw bytes wherever nothing changed (-0.0 and the like cannot creep in)
    changed = depth != raw.depth
    depth = np.where(changed, depth, raw.depth)
    return Rectification(CameraMaps(depth, semantic, instance), transparency, omission, changed)
