"""``carlaocc view`` without a browser, on the shared 0.1 m root: the one-line refusals (no viewer
extra, no root, a prediction on another grid or missing a frame), ``--save`` (one offline HTML
page and the command that opens it), and a prediction tree with errors coloured by outcome,
checked voxel by voxel against the dense grids."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from terminal import from_a_terminal
from typer.testing import CliRunner

from carlaocc.pipeline.cli import app

pytest.importorskip("viser", reason="the viewer extra (pip install 'carlaocc[viewer]'; in the test extra)")


def test_without_the_extra_one_line_naming_it(tmp_path):
    # viser made unimportable in a fresh interpreter: the command names the extra, exit 2
    code = ("import sys; sys.modules['viser'] = None; sys.argv = ['carlaocc', 'view', '--root', %r]\n"
            "from carlaocc.pipeline.cli import main; main()" % str(tmp_path))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        "error: carlaocc view needs the viewer extra (viser is not installed): pip install 'carlaocc[viewer]'"]


def test_a_missing_root_is_refused(tmp_path):
    r = CliRunner().invoke(app, ["view", "--root", str(tmp_path / "nothing")])
    assert r.exit_code == 2 and "error:" in r.output and "nothing" in r.output
    assert not (tmp_path / "nothing").exists()


def test_save_writes_one_offline_page(default_01, tmp_path):
    out = tmp_path / "share" / "frame.html"
    r = CliRunner().invoke(app, ["view", "--root", default_01.url, "--save", str(out), "--frames", "0:1",
                                 "--max-points", "20000"])
    assert r.exit_code == 0, r.output
    html = out.read_text()
    assert html.startswith("<!") and "window.__VISER_EMBED_DATA__=" in html
    assert f"python -m webbrowser -t {out.resolve().as_uri()}" in r.output
    # the scene is inside the page, not fetched: no script or stylesheet from elsewhere
    assert "<script src=\"http" not in html and "<link rel=\"stylesheet\" href=\"http" not in html
    # the recording inside: the scene, and the first view set where the live viewer sets it
    # (behind and above the ego, looking ahead), not viser's default
    messages = _recording(html)
    from carlaocc.pipeline.commands.viewer import INITIAL_CAMERA

    by_type = {}
    for _, m in messages:
        by_type.setdefault(m["type"], []).append(m)
    assert [m["position"] for m in by_type["SetCameraPositionMessage"]] == [list(INITIAL_CAMERA[0])]
    assert [m["look_at"] for m in by_type["SetCameraLookAtMessage"]] == [list(INITIAL_CAMERA[1])]
    assert any(m["name"] == "/voxels/Road" for m in by_type["PointCloudMessage"])
    bad = CliRunner().invoke(app, ["view", "--root", default_01.url, "--save", str(tmp_path / "x.png")])
    assert bad.exit_code == 2 and "--save" in bad.output and not (tmp_path / "x.png").exists()


def _recording(html: str) -> list:
    """The messages of the viser recording a saved page embeds (base64 of viser's zstd framing
    around msgpack: an 8-byte size, then the payload whose first 8 bytes size the metadata)."""
    import base64

    import msgspec
    import zstandard

    raw = base64.b64decode(html.split('window.__VISER_EMBED_DATA__="', 1)[1].split('"', 1)[0])
    inner = zstandard.ZstdDecompressor().decompress(raw[8:], max_output_size=int.from_bytes(raw[:8], "little"))
    n = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8:8 + n])["messages"]


def _dense(s):
    sem = np.zeros(tuple(s["grid_shape"]), np.uint8)
    sem[tuple(s["occ"][:, :3].T)] = s["occ"][:, 3]
    return sem


def test_a_prediction_with_errors_is_coloured_by_outcome(default_01, tmp_path):
    from carlaocc.pipeline.commands.viewer import open_frames, prediction_files, prepare_frame
    from carlaocc.stages.render.viewer import OUTCOMES

    from carlaocc.catalog.samples import FrameSamples

    samples = open_frames(default_01.url, None, 0.1)
    seq, frame = samples.samples[0]
    first = FrameSamples(default_01.url, voxel_size=0.1, occupancy="sparse", cameras=False, lidar=False, boxes=False,
                         sequences=[seq])[0]
    gt = _dense(first)
    # the prediction: ground truth with some voxels dropped, some added, some relabelled
    rng = np.random.default_rng(0)
    pred = gt.copy()
    occ = np.flatnonzero(gt)
    pred.reshape(-1)[rng.choice(occ, 2000, replace=False)] = 0
    pred.reshape(-1)[rng.choice(np.flatnonzero(gt == 0), 2000, replace=False)] = 14
    relabel = rng.choice(occ, 2000, replace=False)
    pred.reshape(-1)[relabel] = np.where(gt.reshape(-1)[relabel] == 9, 10, 9)
    (tmp_path / "pred" / seq).mkdir(parents=True)
    np.savez(tmp_path / "pred" / seq / f"{frame:06d}.npz", semantics=pred)
    files = prediction_files(tmp_path / "pred", seq, [frame])
    v = prepare_frame(samples, 0, files[frame], budget=10**9)
    assert v.occupied == int(((gt > 0) | (pred > 0)).sum())
    # every drawn voxel's outcome and class, against the dense grids at its centre
    ijk = np.floor((v.centres - np.asarray(first["grid_origin"])) / 0.1).astype(int)
    g, p = gt[tuple(ijk.T)], pred[tuple(ijk.T)]
    expect = np.where(g == 0, 1, np.where(p == 0, 2, np.where(g == p, 0, 3)))
    assert np.array_equal(v.outcome, expect)
    assert np.array_equal(v.semantic, np.where(p == 0, g, p))
    assert set(np.unique(v.outcome)) == set(range(len(OUTCOMES)))  # all four outcomes are drawn


def test_the_surface_read_chunk_by_chunk_is_the_whole_frame_s(default_01):
    # read_surface never assembles the frame; the reference: every occupied voxel read whole, then
    # the surface of the whole set
    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.catalog.samples import FrameSamples
    from carlaocc.catalog.store import Store
    from carlaocc.pipeline.commands.viewer import load_masks, open_frames, prepare_frame, read_surface
    from carlaocc.stages.render.viewer import surface_voxels

    samples = open_frames(default_01.url, None, 0.1)
    seq, frame = samples.samples[0]
    full = FrameSamples(default_01.url, voxel_size=0.1, occupancy="sparse", cameras=False, lidar=False, boxes=False,
                        sequences=[seq])[0]
    rows = full["occ"]
    on = surface_voxels(rows[:, :3], full["grid_shape"])
    got = read_surface(OccupancyStore(Store(default_01.url)), seq, samples.grid(seq), frame)
    assert got["occupied"] == len(rows)
    assert np.array_equal(got["ijk"], rows[on, :3])  # the same voxels, in the same (C) order
    assert np.array_equal(got["semantic"], rows[on, 3]) and np.array_equal(got["instance"], full["occ_instance"][on])
    things = full["occ_instance"][on] != 0
    assert things.any() and np.array_equal(got["flow"][things], full["occ_flow"][on][things])
    # the masks, read later at the drawn voxels only
    v = prepare_frame(samples, 0, None, budget=10**9)
    assert v.mask_camera is None and len(v.centres) == int(on.sum())
    load_masks(samples, 0, v)
    assert np.array_equal(v.mask_camera, full["occ_mask_camera"][on])
    assert np.array_equal(v.mask_lidar, full["occ_mask_lidar"][on])
    assert not v.mask_camera.all()  # some surface is unobserved: the comparison means something
    # the live viewer reads them when "unobserved" leaves "show", and ghosts what they mark
    from carlaocc.pipeline.commands.viewer import RootFrames, Viewer, start_server, stop_server

    server = start_server()
    try:
        viewer = Viewer(server, RootFrames(samples), 10**9, prepared={0: prepare_frame(samples, 0, None, 10**9)})
        assert viewer.view(0).mask_camera is None
        viewer.unobserved.value = "ghost"
        viewer.draw()
        assert np.array_equal(viewer.view(0).mask_camera, full["occ_mask_camera"][on])
        assert "error" not in viewer.status.content
    finally:
        stop_server(server)


def test_prediction_refusals(default_01, tmp_path):
    samples_seq = CliRunner().invoke(app, ["view", "--root", default_01.url, "--pred", str(tmp_path / "none"),
                                           "--save", str(tmp_path / "a.html")])
    assert samples_seq.exit_code == 2 and "--pred" in samples_seq.output and "not a directory" in samples_seq.output
    from carlaocc.pipeline.commands.viewer import open_frames

    seq, frame = open_frames(default_01.url, None, 0.1).samples[0]
    (tmp_path / "p" / seq).mkdir(parents=True)
    np.savez(tmp_path / "p" / seq / f"{frame:06d}.npz", semantics=np.zeros((200, 200, 16), np.uint8))
    r = CliRunner().invoke(app, ["view", "--root", default_01.url, "--pred", str(tmp_path / "p"), "--frames", "0:1",
                                 "--save", str(tmp_path / "b.html")])
    assert r.exit_code == 2 and "(200, 200, 16)" in r.output and "root's grid" in r.output, r.output
    r = CliRunner().invoke(app, ["view", "--root", default_01.url, "--pred", str(tmp_path / "p"), "--frames", "1:2",
                                 "--save", str(tmp_path / "b.html")])
    assert r.exit_code == 2 and "no prediction for" in r.output and not (tmp_path / "b.html").exists()


def test_the_command_serves_on_a_free_port_and_stops_on_ctrl_c(default_01):
    import os
    import signal
    import urllib.request

    proc = subprocess.Popen([sys.executable, "-m", "carlaocc", "view", "--root", default_01.url, "--port", "0",
                             "--max-points", "5000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=from_a_terminal)
    try:
        line = proc.stdout.readline()
        assert line.startswith("viewing ") and "http://localhost:" in line, (line, proc.stderr.read()[-2000:])
        url = line.split(": ", 1)[1].split()[0]
        with urllib.request.urlopen(url, timeout=30) as r:
            assert r.status == 200 and b"<html" in r.read(2000).lower()
        # Ctrl-C: the server stops, and the process ends as every command does on a stop signal
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 128 + signal.SIGINT
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()


def test_the_class_legend_gives_each_class_its_palette_colour():
    from carlaocc.pipeline.commands.viewer import class_legend_text
    from carlaocc.schemas import taxonomy

    pal = taxonomy.palette()
    road, car = taxonomy.by_name("Road").id, taxonomy.by_name("Car").id
    sem = class_legend_text([0, road, car], "semantic")
    for cid in (road, car):
        swatch = f"<span style='color:rgb{tuple(int(x) for x in pal[cid])}'>&#9632;</span> {taxonomy.by_id(cid).name}"
        assert swatch in sem
    assert sem.count("&#9632;") == 2  # the empty class 0 has no swatch
    # by instance: things have no class colour, stuff keeps its swatch
    inst = class_legend_text([road, car], "instance")
    assert "Road" in inst and "Car" not in inst and "a colour per instance" in inst
    assert class_legend_text([road, car], "outcome") == ""
