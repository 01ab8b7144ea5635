"""Skeletal Motion Analyzer: forward kinematics, gait cycles of the real CMU walk, the procedural
walker, and phase-matching accuracy on noisy synthetic walks observed at 20 Hz."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from carlaocc.stages.scenes.people import gait
from carlaocc.stages.scenes.people.gait.cycles import canonical_cycle, detect_gait_cycles
from carlaocc.stages.scenes.people.gait.kinematics import (
    BVH_TO_ZUP, clip_positions, forward_kinematics, select_gait_joints,
)
from carlaocc.stages.scenes.people.gait.matching import GaitModel, phase_accuracy
from carlaocc.stages.scenes.people.gait.walker import add_joint_noise, procedural_walk, resample_walk
from shared_data import require, shared_path

GAIT = "carlaocc.stages.scenes.people.gait."

CLIP = shared_path("motion/cmu_131_01_walk_metres.bvh")
SPEEDS = (0.8, 1.2, 1.6)
NOISES = (0.0, 0.01, 0.02, 0.03)  # metres, std of Gaussian noise per joint coordinate
TRAIN_SPEEDS = (0.7, 0.9, 1.1, 1.3, 1.5, 1.7)
D, W, RATE = 32, 11, 20.0


@pytest.fixture(scope="module")
def cmu():
    from carlaocc.catalog.bvh import read_bvh  # tests may cross layers; the module under test does not

    clip = read_bvh(str(require(CLIP)))
    pos = clip_positions(clip)
    t = np.arange(clip.n_frames) * clip.frame_time
    g = select_gait_joints(clip.joint_names, pos)
    return clip, pos, t, g, detect_gait_cycles(g, t)


# --------------------------------------------------------------------------- forward kinematics


def test_fk_tiny_chain_and_zup():
    parents = [-1, 0, 1]
    offsets = np.array([[0, 0, 0], [0, -1.0, 0], [0, -1.0, 0]])
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"), ("Xrotation",), ()]
    motion = np.array([[1.0, 2.0, 3.0, 0, 0, 0, 0.0], [0, 0, 0, 90.0, 0, 0, 90.0]])
    p = forward_kinematics(parents, offsets, channels, motion, zup=False)
    np.testing.assert_allclose(p[0], [[1, 2, 3], [1, 1, 3], [1, 0, 3]], atol=1e-12)
    # frame 1: root yawed 90 deg about Z (BVH) sends -Y to +X; the knee bends 90 deg about X
    np.testing.assert_allclose(p[1], [[0, 0, 0], [1, 0, 0], [1, 0, -1]], atol=1e-12)
    pz = forward_kinematics(parents, offsets, channels, motion)
    np.testing.assert_allclose(pz, p[..., [2, 0, 1]])  # ours = (z, x, y)_bvh
    assert np.linalg.det(BVH_TO_ZUP) == pytest.approx(1.0)


def test_fk_real_clip_walks_forward(cmu):
    clip, pos, t, g, cyc = cmu
    assert pos.shape == (995, 31, 3)
    w = cyc.walking
    assert w.sum() > 200
    # Z up: pelvis ~0.9 m above the lowest ankle, head above pelvis
    head = clip.joint_names.index("Head")
    assert 0.7 < np.median(g[w, 0, 2] - np.minimum(g[w, 3, 2], g[w, 6, 2])) < 1.0
    assert (pos[w, head, 2] > g[w, 0, 2] + 0.3).all()
    # steady walking segment at a walking speed, moving along its heading
    assert 1.0 <= cyc.speed[w].mean() <= 1.6
    idx = np.flatnonzero(w)
    disp = g[idx[-1], 0] - g[idx[0], 0]
    assert np.linalg.norm(disp[:2]) > 2.0  # ~2.3 s of walking
    assert np.dot(disp, cyc.forward[idx].mean(axis=0)) > 0.8 * np.linalg.norm(disp[:2])
    # left hip on the left of the heading (a proper rotation kept the skeleton's handedness)
    assert np.mean(np.cross(cyc.forward[idx], g[idx, 1] - g[idx, 4])[:, 2]) > 0.05


def test_feet_alternate(cmu):
    _, _, t, g, cyc = cmu
    dx = cyc.dx[cyc.walking]
    assert dx.max() > 0.5 and dx.min() < -0.5  # each foot in turn ~half a leg ahead
    crossings = np.flatnonzero(np.diff(np.sign(dx)) != 0)
    assert len(crossings) >= 3
    # the foot in front alternates with a step period of half a cycle
    steps = np.diff(t[cyc.walking][crossings])
    assert np.all(np.abs(steps - cyc.period / 2) < 0.25 * cyc.period)


def test_gait_period_and_canonical_cycle(cmu):
    clip, pos, t, g, cyc = cmu
    assert 1.0 <= cyc.period <= 1.2
    assert len(cyc.events) >= 2
    labelled = ~np.isnan(cyc.phases)
    assert labelled.sum() > 150 and np.all(cyc.walking[labelled])
    cc = canonical_cycle(pos, t, D, cycles=cyc, pelvis=clip.joint_names.index("Hips"), gait=g)
    assert cc.poses.shape == (D, 31, 3) and cc.features.shape == (D, 5)
    assert 1.0 <= cc.period <= 1.2 and 1.0 <= cc.speed <= 1.6
    np.testing.assert_allclose(cc.pose(0)[0, :2], 0.0, atol=1e-9)  # pelvis at the origin
    assert cc.features[0, 0] == cc.features[:, 0].max()  # phase 0: left ankle furthest ahead
    assert cc.features[D // 2, 0] < -0.5  # half a cycle later the right one is


# --------------------------------------------------------------------------- procedural walker


@pytest.mark.parametrize("speed", SPEEDS)
def test_procedural_walker(speed):
    walk = procedural_walk(speed, 5.0, rate=100.0, heading=0.7)
    p = walk.positions
    assert p.shape == (500, 7, 3)
    v = (p[-1, 0] - p[0, 0]) / (walk.times[-1] - walk.times[0])
    assert np.linalg.norm(v[:2]) == pytest.approx(speed)
    assert np.arctan2(v[1], v[0]) == pytest.approx(0.7)
    assert np.minimum(p[:, 3, 2], p[:, 6, 2]).min() == pytest.approx(0.08)  # a foot on the ground
    cyc = detect_gait_cycles(p, walk.times)
    stride = 1.5 * 0.88 * np.sqrt(speed / 1.2)
    assert cyc.period == pytest.approx(stride / speed, rel=0.02)
    # detected phase-0 events coincide with the analytic phase 0
    ph = np.interp(cyc.events[1:], walk.times, np.unwrap(walk.phases * 2 * np.pi) / (2 * np.pi))
    assert np.all(np.abs((ph + 0.5) % 1.0 - 0.5) < 0.01)


# --------------------------------------------------------------------------- phase accuracy


def _walker(speed, sigma, rng, duration=6.0):
    s = rng.uniform(0.9, 1.1)  # body size
    walk = procedural_walk(
        speed, duration, RATE, heading=rng.uniform(-np.pi, np.pi), phase0=rng.uniform(), thigh=0.45 * s, shin=0.43 * s
    )
    return add_joint_noise(walk, sigma, rng)


def _bvh_source(cmu):
    _, _, t, g, cyc = cmu
    base = cyc.speed[~np.isnan(cyc.phases)].mean()

    def make(speed, sigma, rng):
        walk = resample_walk(g, t, cyc.phases, speed / base, RATE, t_offset=rng.uniform(0, 1 / RATE))
        return add_joint_noise(walk, sigma, rng)

    return make


def _accuracy_table(source, reps, seed):
    rng = np.random.default_rng(seed)
    train = [source(sp, sig, rng) for sp in TRAIN_SPEEDS for sig in NOISES for _ in range(reps)]
    model = GaitModel.fit(train, D=D, W=W)
    table = np.zeros((len(SPEEDS), len(NOISES) + 1))
    for i, sp in enumerate(SPEEDS):
        for j, sig in enumerate(NOISES + (0.05,)):
            tests = [source(sp, sig, np.random.default_rng(seed + 1000 + 100 * i + 10 * j + r)) for r in range(reps)]
            table[i, j] = np.mean([phase_accuracy(model, w, tolerance=1) for w in tests])
    return model, table


def test_phase_accuracy_procedural_walker():
    model, table = _accuracy_table(_walker, reps=2, seed=7)
    print("\nprocedural walker, accuracy within +-1 phase (rows speed, cols noise m):", NOISES + (0.05,))
    for sp, row in zip(SPEEDS, table):
        print(sp, np.round(row, 3))
    assert model.means.shape == (D, 10) and model.var.shape == (10,)
    assert table[:, :-1].min() >= 0.97  # noise up to 3 cm
    assert table[:, -1].min() >= 0.9  # 5 cm (outside the calibration range)


def test_phase_accuracy_cmu_walk(cmu):
    model, table = _accuracy_table(_bvh_source(cmu), reps=3, seed=11)
    print("\nCMU walk resampled, accuracy within +-1 phase (rows speed, cols noise m):", NOISES + (0.05,))
    for sp, row in zip(SPEEDS, table):
        print(sp, np.round(row, 3))
    assert table[:, :-1].mean() >= 0.97
    assert table[:, :-1].min() >= 0.95
    assert table[:, -1].min() >= 0.9


def test_phase_returns_index_and_log_likelihood():
    rng = np.random.default_rng(3)
    model = GaitModel.fit([_walker(sp, 0.01, rng) for sp in TRAIN_SPEEDS], D=D, W=W)
    walk = procedural_walk(1.2, 2.0, RATE, phase0=0.3)
    d, ll = model.phase(walk.positions[:W], walk.times[:W])
    assert isinstance(d, int) and 0 <= d < D and np.isfinite(ll)
    m = model.match(walk.positions[:W])  # default 20 Hz spacing
    assert m.phase == d and m.log_likelihood == pytest.approx(ll) and not m.standing
    assert m.log_likelihoods.shape == (D,) and ll == pytest.approx(m.log_likelihoods.max())
    true = np.round(walk.phases[W // 2] * D) % D
    assert abs((d - true + D // 2) % D - D // 2) <= 1


@pytest.mark.parametrize("sigma", [0.0, 0.03])
def test_standing_still_has_no_phase(sigma):
    rng = np.random.default_rng(5)
    model = GaitModel.fit([_walker(sp, 0.01, rng) for sp in TRAIN_SPEEDS], D=D, W=W)
    still = add_joint_noise(procedural_walk(0.0, 3.0, RATE, heading=1.0), sigma, rng)
    assert np.isnan(still.phases).all()
    for s in range(0, len(still.times) - W + 1, 3):
        m = model.match(still.positions[s : s + W], still.times[s : s + W])
        assert m.standing and m.phase is None and m.speed < model.standing_speed
        assert model.phase(still.positions[s : s + W])[0] is None


def test_gait_modules_are_pure_compute():
    files = sorted(Path(gait.__file__).parent.glob("*.py"))
    assert {f.stem for f in files} == {"__init__", "kinematics", "descriptor", "cycles", "walker", "matching"}
    for path in files:
        src = path.read_text()
        mods = set()
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, ast.Import):
                mods |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                mods.add(node.module)
        ours = {m for m in mods if m.startswith("carlaocc.")}
        assert mods - ours <= {"__future__", "collections.abc", "dataclasses", "typing", "numpy"}, path.name
        assert all(m == "carlaocc.schemas.motion" or m.startswith(GAIT) for m in ours), path.name
        assert "open(" not in src
