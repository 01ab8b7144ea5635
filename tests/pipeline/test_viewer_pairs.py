"""``carlaocc view --pred P --gt G [--map M]``: a prediction tree against its ground-truth tree, any
pair ``carlaocc eval ssc`` reads, drawn on the grid and in the frame the export's ``grid.json``
states. Ground truth from our own exporters run on the shared 0.1 m root (Occ3D, carlaocc-npz, the
release layout), predictions made from it with known errors in the forms eval reads (one-array
.npy, npz 'semantics'); every drawn voxel's outcome and class checked against the dense grids at
its centre, placed by grid.json."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.pipeline.cli import app

pytest.importorskip("viser", reason="the viewer extra (pip install 'carlaocc[viewer]'; in the test extra)")

SEQ = "town00_high_seq000"


def _errors(sem: np.ndarray, free: int, classes: tuple[int, int], seed: int = 0) -> np.ndarray:
    """``sem`` with known errors: some occupied voxels made free, some free ones filled with
    ``classes[0]``, some relabelled ``classes[1]``."""
    rng = np.random.default_rng(seed)
    out = sem.copy()
    occ = np.flatnonzero(sem != free)
    n = max(len(occ) // 20, 1)
    out.reshape(-1)[rng.choice(occ, n, replace=False)] = free
    out.reshape(-1)[rng.choice(np.flatnonzero(sem == free), n, replace=False)] = classes[0]
    out.reshape(-1)[rng.choice(occ, n, replace=False)] = classes[1]
    return out


def _check_against_dense(v, gt: np.ndarray, pred: np.ndarray, free: int, origin, voxel_size: float) -> None:
    """Every drawn voxel's outcome and shown class, read back from the dense grids at its centre."""
    ijk = np.floor((v.centres - np.asarray(origin)) / voxel_size).astype(int)
    g, p = gt[tuple(ijk.T)].astype(int), pred[tuple(ijk.T)].astype(int)
    expect = np.where(g == free, 1, np.where(p == free, 2, np.where(g == p, 0, 3)))
    assert np.array_equal(v.outcome, expect)
    assert np.array_equal(v.semantic, np.where(p == free, g, p))
    assert set(np.unique(v.outcome)) == {0, 1, 2, 3}
    assert v.occupied == int(((gt != free) | (pred != free)).sum())


def test_occ3d_tree_on_the_ego_grid_with_its_masks(default_01, tmp_path):
    from carlaocc.pipeline.commands.viewer_pairs import pair_frames

    out = tmp_path / "occ3d"
    r = CliRunner().invoke(app, ["export", "occ3d", "--res", "0.1", "--root", default_01.url, "--out", str(out),
                                 "--sequence", SEQ])
    assert r.exit_code == 0, r.output
    grid = json.loads((out / "grid.json").read_text())
    files = sorted(out.glob("gts/*/*/labels.npz"))
    assert len(files) == 2
    # predictions as one-array .npy files at the same relative paths (eval reads those)
    preds = {}
    for f in files:
        sem = np.load(f)["semantics"]
        preds[f] = _errors(sem, 17, (4, 16))  # car where nothing is; vegetation instead
        dst = tmp_path / "pred" / f.relative_to(out).with_suffix(".npy")
        dst.parent.mkdir(parents=True, exist_ok=True)
        np.save(dst, preds[f])
    src = pair_frames(tmp_path / "pred", out, "occ3d")
    assert len(src) == 2 and src.labels.names[4] == "car"
    v = src.prepare(0, 10**9)
    with np.load(files[0]) as z:
        gt, mcam = z["semantics"], z["mask_camera"].astype(bool)
    _check_against_dense(v, gt, preds[files[0]], 17, grid["origin"], grid["voxel_size"])
    assert np.array_equal(v.ego, np.eye(4))  # the Occ3D grid is in the ego frame: the ego at its origin
    # the masks are the ground truth's, at each drawn voxel
    ijk = np.floor((v.centres - np.asarray(grid["origin"])) / grid["voxel_size"]).astype(int)
    assert np.array_equal(v.mask_camera, mcam[tuple(ijk.T)]) and not v.mask_camera.all()
    # the colours come from the Occ3D ids: car drawn in the Car colour
    from carlaocc.schemas.taxonomy import by_name, palette

    assert tuple(src.labels.colours[4]) == tuple(palette()[by_name("Car").id])
    # with the root: its boxes and cameras on the frame the path names, moved into the ego frame
    from carlaocc.catalog.samples import FrameSamples
    from carlaocc.pipeline.commands.viewer import RootFrames, open_frames
    from carlaocc.pipeline.commands.viewer_pairs import sample_of_key

    samples = open_frames(default_01.url, SEQ, 0.1)
    key = src.names[0]  # gts/<seq>/<seq>_<frame:06d>/labels
    at = sample_of_key(key, samples)
    assert samples.samples[at] == (SEQ, int(key.split("/")[2].rsplit("_", 1)[1]))
    rooted = src.with_root(default_01.url).prepare(0, 10**9)
    plain = RootFrames(samples).prepare(at, 10**9)  # the same frame in the LiDAR frame
    to_ego = FrameSamples(default_01.url, occupancy="none", cameras=False, lidar=False, boxes=False,
                          sequences=[SEQ])[at]["lidar_to_ego"]
    assert len(plain.boxes) and len(rooted.cameras) == len(plain.cameras) > 0
    np.testing.assert_allclose(rooted.boxes, plain.boxes @ to_ego[:3, :3].T + to_ego[:3, 3], atol=1e-4)
    np.testing.assert_allclose([c["position"] for c in rooted.cameras],
                               [to_ego[:3, :3] @ c["position"] + to_ego[:3, 3] for c in plain.cameras], atol=1e-9)
    np.testing.assert_allclose(rooted.ego, np.eye(4), atol=1e-9)  # the ego at the Occ3D grid's origin
    assert np.array_equal(rooted.outcome, v.outcome)  # the voxels are the trees' whatever the root
    # the live viewer's status line names the frame by its path, breakable at each "/" (a long
    # path does not run out of the panel)
    from carlaocc.pipeline.commands.viewer import Viewer, start_server, stop_server

    server = start_server()
    try:
        viewer = Viewer(server, src, 10**9, prepared={0: v})
        status = viewer.status.content
        assert "error" not in status and key.replace("/", "/\u200b") in status
    finally:
        stop_server(server)
    # the command: one offline page of the pair
    page = tmp_path / "pair.html"
    r = CliRunner().invoke(app, ["view", "--pred", str(tmp_path / "pred"), "--gt", str(out), "--map", "occ3d",
                                 "--save", str(page)])
    assert r.exit_code == 0, r.output
    assert "2 frame(s)" in r.output and "window.__VISER_EMBED_DATA__=" in page.read_text()


def test_carlaocc_npz_tree_on_the_lidar_grid(default_01, tmp_path):
    from carlaocc.catalog.formats import load_carlaocc_npz
    from carlaocc.pipeline.commands.viewer_pairs import pair_frames

    out = tmp_path / "npz"
    r = CliRunner().invoke(app, ["export", "carlaocc-npz", "--res", "0.1", "--root", default_01.url, "--out", str(out),
                                 "--sequence", SEQ])
    assert r.exit_code == 0, r.output
    grid = json.loads((out / "grid.json").read_text())
    assert grid["frame"].startswith("lidar")
    f, *others = sorted(out.glob(f"{SEQ}/*.npz"))
    for other in others:  # one frame is enough (a 0.1 m grid is 51 M voxels)
        other.unlink()
    gt = load_carlaocc_npz(f).semantic
    pred = _errors(gt, 0, (14, 9), seed=1)
    dst = tmp_path / "pred" / f.relative_to(out)
    dst.parent.mkdir(parents=True)
    np.savez(dst, semantics=pred)  # a model's dense output in CarlaOcc ids
    src = pair_frames(tmp_path / "pred", out, "carlaocc")
    v = src.prepare(0, 10**9)
    _check_against_dense(v, gt, pred, 0, grid["origin"], grid["voxel_size"])
    assert v.ego is None  # the LiDAR frame: where the ego is, the tree does not say
    # the instances come with the ground truth's CarlaOcc npz: things can be coloured by instance
    inst = load_carlaocc_npz(f).instance
    ijk = np.floor((v.centres - np.asarray(grid["origin"])) / grid["voxel_size"]).astype(int)
    assert v.instance.any() and np.array_equal(v.instance, inst[tuple(ijk.T)])


def test_release_tree_takes_the_grid_of_its_folder(release_01, tmp_path):
    from carlaocc.catalog.formats import load_carlaocc_npz
    from carlaocc.pipeline.commands.viewer_pairs import pair_frames

    grids = {g["folder"]: g for g in json.loads((release_01 / "grid.json").read_text())["grids"]}
    folder = sorted(release_01.glob("*/occupancy/vs_0_2_forward_view"))[0]
    files = sorted(folder.glob("*.npz"))
    preds = {}
    for f in files:
        gt = load_carlaocc_npz(f).semantic
        preds[f] = _errors(gt, 0, (14, 10), seed=2)
        (tmp_path / "pred").mkdir(exist_ok=True)
        np.save(tmp_path / "pred" / f"{f.stem}.npy", preds[f])
    # --gt a folder deep in the release tree: its grid.json is the tree's, the grid its folder's
    src = pair_frames(tmp_path / "pred", folder, "carlaocc")
    g = grids["vs_0_2_forward_view"]
    assert src.grids[0]["origin"] == tuple(g["origin"]) and src.voxel_size == g["voxel_size"]
    _check_against_dense(src.prepare(0, 10**9), load_carlaocc_npz(files[0]).semantic, preds[files[0]], 0,
                         g["origin"], g["voxel_size"])


def test_pair_refusals_are_one_line(default_01, tmp_path):
    out = tmp_path / "occ3d"
    r = CliRunner().invoke(app, ["export", "occ3d", "--res", "0.1", "--root", default_01.url, "--out", str(out),
                                 "--sequence", SEQ])
    assert r.exit_code == 0, r.output
    files = sorted(out.glob("gts/*/*/labels.npz"))
    pred = tmp_path / "pred"
    for f in files:
        (pred / f.relative_to(out)).parent.mkdir(parents=True, exist_ok=True)
        np.savez(pred / f.relative_to(out), semantics=np.load(f)["semantics"])

    def refused(*args: str) -> str:
        page = tmp_path / "x.html"
        r = CliRunner().invoke(app, ["view", *args, "--save", str(page)])
        assert r.exit_code == 2 and not page.exists(), r.output
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), r.output
        return lines[0]

    # labels of another space: Occ3D's 17 (free) is no benchmark id
    assert "is not an id of --map benchmark" in refused("--pred", str(pred), "--gt", str(out), "--map", "benchmark")
    assert "--map" in refused("--pred", str(pred), "--gt", str(out), "--map", "nuscenes")
    assert "needs --pred" in refused("--gt", str(out))
    assert "applies to --pred with --gt" in refused("--root", default_01.url, "--map", "occ3d")
    # a --root given with --gt is read (its overlays), so a wrong one is refused
    assert "--root" in refused("--pred", str(pred), "--gt", str(out), "--map", "occ3d", "--root", str(tmp_path / "none"))
    # a prediction of another shape
    np.savez(pred / files[0].relative_to(out), semantics=np.zeros((100, 100, 8), np.uint8))
    assert "differs from the ground truth" in refused("--pred", str(pred), "--gt", str(out), "--map", "occ3d")
    # a missing counterpart: eval's pairing message
    (pred / files[0].relative_to(out)).unlink()
    assert "no prediction for" in refused("--pred", str(pred), "--gt", str(out), "--map", "occ3d")
