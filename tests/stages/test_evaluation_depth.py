"""Depth metrics on hand-computed values: the cap, the valid mask, clipping, median scaling, and
the pixel-pooled versus per-image averages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carlaocc.stages.evaluation.depth import DepthAccumulator


def test_hand_values_pixel_and_image_averages():
    # image 1: gt 1, 2, 4 valid; 0 (no depth) and 100 (beyond the 80 m cap) invalid
    g1 = np.array([[1.0, 2.0, 4.0, 0.0, 100.0]])
    p1 = np.array([[2.0, 2.0, 3.0, 5.0, 5.0]])
    # d = (1, 0, -1): abs_rel = (1 + 0 + 1/4) / 3, sq_rel = (1 + 0 + 1/4) / 3, rmse = sqrt(2/3),
    # rmse_log = sqrt((ln 2)^2 + (ln 3/4)^2) / 3); ratios 2, 1, 4/3: a1 = 1/3, a2 = a3 = 2/3
    # (2 > 1.25^3 = 1.953)
    g2 = np.array([[10.0]])
    p2 = np.array([[10.0]])  # perfect: every error 0, every accuracy 1
    acc = DepthAccumulator()
    acc.update(p1, g1)
    acc.update(p2, g2)
    r = acc.result()
    img1 = {"abs_rel": 1.25 / 3, "sq_rel": 1.25 / 3, "rmse": math.sqrt(2 / 3),
            "rmse_log": math.sqrt((math.log(2) ** 2 + math.log(0.75) ** 2) / 3), "a1": 1 / 3, "a2": 2 / 3, "a3": 2 / 3}
    img2 = {"abs_rel": 0, "sq_rel": 0, "rmse": 0, "rmse_log": 0, "a1": 1, "a2": 1, "a3": 1}
    for k in img1:
        assert r.image[k] == pytest.approx((img1[k] + img2[k]) / 2), k
    # pooled over the 4 valid pixels
    assert r.pixel["abs_rel"] == pytest.approx(1.25 / 4)
    assert r.pixel["rmse"] == pytest.approx(math.sqrt(2 / 4))
    assert r.pixel["rmse_log"] == pytest.approx(math.sqrt((math.log(2) ** 2 + math.log(0.75) ** 2) / 4))
    assert r.pixel["a1"] == pytest.approx(2 / 4) and r.pixel["a3"] == pytest.approx(3 / 4)
    assert (r.pixels, r.images, r.valid_images) == (4, 2, 2)


def test_clipping_cap_and_mask():
    gt = np.array([5.0, 5.0, 5.0, 50.0])
    pred = np.array([0.0, -3.0, 500.0, 50.0])
    acc = DepthAccumulator(min_depth=1.0, max_depth=10.0)
    acc.update(pred, gt, mask=np.array([True, True, True, True]))
    r = acc.result()
    # gt 50 is beyond the cap; predictions clipped to 1, 1, 10: |d|/g = 0.8, 0.8, 1.0
    assert r.pixels == 3 and r.pixel["abs_rel"] == pytest.approx(2.6 / 3)
    m = DepthAccumulator(min_depth=1.0, max_depth=10.0)
    m.update(pred, gt, mask=np.array([False, False, True, True]))
    assert m.result().pixels == 1 and m.result().pixel["abs_rel"] == pytest.approx(1.0)


def test_median_scaling_recovers_a_scaled_prediction():
    rng = np.random.default_rng(1)
    gt = rng.uniform(2, 60, (12, 20))
    acc = DepthAccumulator(scale="median")
    acc.update(gt / 7.5, gt)
    r = acc.result()
    assert r.pixel["abs_rel"] == pytest.approx(0, abs=1e-12) and r.pixel["a1"] == 1.0


def test_images_without_valid_pixels_and_bad_input():
    acc = DepthAccumulator()
    acc.update(np.ones((2, 2)), np.zeros((2, 2)))
    r = acc.result()
    assert r.valid_images == 0 and math.isnan(r.pixel["rmse"]) and math.isnan(r.image["rmse"])
    with pytest.raises(ValueError, match="shape"):
        acc.update(np.ones((2, 2)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        acc.update(np.full((1, 2), np.nan), np.ones((1, 2)))
    with pytest.raises(ValueError, match="min_depth < max_depth"):
        DepthAccumulator(min_depth=5, max_depth=1)
    with pytest.raises(ValueError, match="scale"):
        DepthAccumulator(scale="lstsq")
