"""The sensors stage's compiled per-pixel kernels against the code they replace: D2NT normals
against the ``d2nt`` package itself (bit for bit), RGB shading against the numpy shading."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.sensors.normals import VERSIONS, depth_normals, reference_normals


def _depth(seed: int, H: int, W: int) -> np.ndarray:
    """A depth map with what D2NT's branches meet: tilted planes, depth steps, noise, holes,
    equal neighbours (flat runs) and the void along whole rows or columns."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    d = rng.uniform(0.5, 80.0) + rng.normal(0, 0.05) * u + rng.normal(0, 0.05) * v
    d = d + rng.uniform(0, 20.0) * (u > rng.integers(0, W + 1)) + rng.normal(0, 0.02, (H, W)) * rng.integers(0, 2)
    d = np.round(d, int(rng.integers(1, 4))) if rng.random() < 0.3 else d  # flat runs: exact ties
    d = np.maximum(d, 0.1).astype(np.float32)
    d[rng.random((H, W)) < rng.uniform(0, 0.2)] = 0.0
    if rng.random() < 0.2:
        d[: rng.integers(0, H + 1)] = 0.0
    return d


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 24), st.integers(1, 24))
def test_d2nt_kernel_equals_the_d2nt_package(seed, H, W):
    depth = _depth(seed, H, W)
    rng = np.random.default_rng(seed + 1)
    f = rng.uniform(50, 1500)
    K = np.array([[f, 0, rng.uniform(0, W)], [0, f * rng.uniform(0.8, 1.2), rng.uniform(0, H)], [0, 0, 1]])
    for version in VERSIONS:
        ours, ref = depth_normals(depth, K, version), reference_normals(depth, K, version)
        assert ours.dtype == np.float32 and ours.shape == (H, W, 3)
        # the same float32 operations in the same order: the same bits
        assert np.array_equal(ours.view(np.uint32), ref.view(np.uint32)), version


def test_d2nt_kernel_equals_the_package_on_a_camera_image():
    # a full rig image (1408 x 376): the borders, the soft-min's padding and v3's argmin at scale
    from carlaocc.schemas.rig import RigConfig

    cam = RigConfig().cameras[0]
    depth = _depth(7, cam.height, cam.width)
    for version in VERSIONS:
        assert np.array_equal(depth_normals(depth, cam.intrinsics, version), reference_normals(depth, cam.intrinsics, version))
