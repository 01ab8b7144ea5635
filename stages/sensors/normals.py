"""Surface normals from a depth map with D2NT (Feng et al., "D2NT: A High-Performing
Depth-to-Normal Translator", the ``d2nt`` package on PyPI, MIT licence, by the paper's authors).

D2NT differentiates the depth image and maps the gradients straight to normals in the camera
frame (OpenCV: x right, y down, z forward); we use its public ``depth2normal``. Two conventions
are adapted here:

* D2NT numbers pixels from 1 (``u = 1..W``); our pixel ``u`` (from 0) has its centre at
  ``u + 0.5``. Passing the principal point as ``cx + 0.5`` makes D2NT's ``u - u0`` equal
  ``(u + 0.5) - cx``.
* Pixels without a surface (depth 0) get the zero vector, and so do pixels whose 3x3
  neighbourhood reaches one (their gradient would mix a surface with the void).

Normals point towards the camera (negative z for a visible surface), as D2NT returns them.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

VERSIONS = ("d2nt_basic", "d2nt_v2", "d2nt_v3")


def depth_normals(depth: np.ndarray, intrinsics, version: str = "d2nt_v2") -> np.ndarray:
    """(H, W, 3) float32 unit normals of a planar depth map (float32 metres, 0 = no surface) in
    the OpenCV camera frame; ``intrinsics`` the 3x3 K of the camera (pixel centres at u + 0.5)."""
    from d2nt import depth2normal  # with cv2, 0.3 s to import: paid only by the normals

    if version not in VERSIONS:
        raise ValueError(f"unknown D2NT version {version!r}; one of {', '.join(VERSIONS)}")
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    K = np.array(intrinsics, dtype=np.float64).reshape(3, 3)
    # 1. D2NT's 1-based pixel numbering: shift the principal point by half a pixel
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    # 2. fill the void with the nearest-free stand-in D2NT can differentiate (masked out below)
    valid = depth > 0
    if not valid.any():
        return np.zeros((*depth.shape, 3), dtype=np.float32)
    filled = np.where(valid, depth, np.float32(depth[valid].max()))
    n = depth2normal(filled, K, version=version).astype(np.float32, copy=False)
    # 3. zero where the 3x3 neighbourhood touches a pixel without a surface
    keep = minimum_filter(valid.view(np.uint8), size=3, mode="nearest").astype(bool)
    n[~keep] = 0.0
    return n
