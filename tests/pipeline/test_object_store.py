"""A dataset root on an S3-compatible object store: moto's S3 server, started by the test on
127.0.0.1 and stopped after (no network beyond loopback). One sequence is built to
``s3://<bucket>/...`` through every stage and compared byte for byte with the same build in a
directory; ``status`` reads it, a re-run skips everything, a driver killed mid-run resumes to the
same bytes, SQL runs over its catalog and the loader reads a sample from it."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig

VOXEL_SIZE = 0.4
SEQ = "town00_high_seq000"
# one sequence of 2 frames, one camera, one procedural variant per sub-class: every stage
CONFIG = DatasetConfig.model_validate({"ingest": {"variants_per_subclass": 1}, "scenes": {"frame_count": 2},
                                       "sensors": {"cameras": ["camera_00"]}})
cli = CliRunner()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def s3():
    """moto's S3 server on 127.0.0.1 (a thread of this process: the driver's subprocess and any
    worker process reach it over loopback), credentials and endpoint in the environment every
    process inherits, one bucket; yields its ``s3://`` URL and stops the server after."""
    import logging

    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line per request
    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    env = {"AWS_ACCESS_KEY_ID": "carlaocc-test", "AWS_SECRET_ACCESS_KEY": "carlaocc-test",
           "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        import s3fs

        s3fs.S3FileSystem.clear_instance_cache()
        s3fs.S3FileSystem().mkdir("carlaocc-test")
        yield "s3://carlaocc-test"
    finally:
        server.stop()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@pytest.fixture(scope="module")
def config_file(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("s3_config") / "config.json"
    path.write_text(CONFIG.model_dump_json())
    return str(path)


def _args(config_file: str, root: str) -> list[str]:
    return ["--config", config_file, "--res", str(VOXEL_SIZE), "--root", root, "--sequences", SEQ]


def _run(config_file: str, root: str):
    r = cli.invoke(app, ["run", *_args(config_file, root), "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return r


def _objects(store: Store) -> dict[str, bytes]:
    """Every stored object's bytes by store-relative path, but what differs by run and not by
    data: lineage (run ids, times), the report page and its plots (times, the root's name)."""
    fs, base = store.fs, store.root.rstrip("/")
    rels = [p[len(base) + 1:] for p in fs.find(base)]
    return {rel: fs.cat_file(f"{base}/{rel}") for rel in rels
            if not rel.startswith(("catalog/runs/", "metrics/plots/")) and rel != "metrics/report.html"
            and not rel.rsplit("/", 1)[-1].startswith(".")}


def test_a_root_on_s3_survives_a_killed_driver_and_matches_a_directory(s3, config_file, tmp_path):
    # the same build in a directory, for the bytes
    directory = Store(str(tmp_path / "data"))
    _run(config_file, directory.root)
    # on the object store: the driver is killed once the first frame's voxels are stored ...
    root = f"{s3}/dataset"
    store = Store(root)
    proc = subprocess.Popen([sys.executable, "-m", "carlaocc", "run", *_args(config_file, root), "--scheduler",
                             "synchronous"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if store.glob(f"occupancy.zarr/{SEQ}/{VOXEL_SIZE}/semantic/c", ""):
                break
            time.sleep(0.1)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert not store.exists("metrics/report.html")  # it was stopped mid-way
    # ... and the run started again finishes it: the same bytes as the directory's build
    r = _run(config_file, root)
    ran, total = map(int, re.search(r"done: ran (\d+) of (\d+) tasks", r.output).groups())
    assert 0 < ran < total and "ingest: 1 up to date" in r.output  # what it had finished is not redone
    on_s3, on_disk = _objects(store), _objects(directory)
    assert on_s3.keys() == on_disk.keys()
    assert [k for k in on_s3 if on_s3[k] != on_disk[k]] == []
    for part in (f"occupancy.zarr/{SEQ}/", f"sensors.zarr/{SEQ}/", f"lidar/{SEQ}/", f"metrics/quality/{SEQ}/",
                 "admesh/", "scenes/", "splits/"):
        assert any(k.startswith(part) for k in on_s3), part
    # listings are never cached; a frame's stat signature comes from the objects' ETags (so status
    # trusts the recorded fingerprints and reads no chunk)
    from carlaocc.catalog.signatures import frame_signature

    assert not store.fs.dircache.use_listings_cache
    assert frame_signature(store, "occupancy.zarr", f"{SEQ}/{VOXEL_SIZE}/semantic", 0) is not None
    # status from the object store (signatures from the ETags): everything up to date
    r = cli.invoke(app, ["status", *_args(config_file, root)])
    assert r.exit_code == 0, r.output
    assert "up to date" in r.output and "stale" not in r.output and "missing" not in r.output, r.output
    # a run again runs nothing and writes nothing
    r = _run(config_file, root)
    assert f"nothing to do: all {total} tasks up to date in {root}" in r.output, r.output
    assert _objects(store) == on_s3
    # SQL over its catalog
    r = cli.invoke(app, ["catalog", "query", "--root", root,
                         f"SELECT count(*) AS n FROM frames WHERE sequence_id = '{SEQ}'"])
    assert r.exit_code == 0, r.output
    assert r.output.split()[:3] == ["n", "-", str(CONFIG.scenes.frame_count)], r.output
    # an export read from the object store: the same files as from the directory
    outs = {}
    for name, src in (("s3", root), ("dir", directory.root)):
        outs[name] = tmp_path / f"occ3d-{name}"
        r = cli.invoke(app, ["export", "occ3d", "--res", str(VOXEL_SIZE), "--root", src, "--out", str(outs[name]),
                             "--sequence", SEQ])
        assert r.exit_code == 0, r.output
    files = {name: {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
             for name, out in outs.items()}
    assert files["s3"].keys() == files["dir"].keys() and any(k.name == "labels.npz" for k in files["s3"])
    assert [k for k in files["s3"] if files["s3"][k] != files["dir"][k]] == []
    # a sample through the loader, equal to the directory's
    from carlaocc.data import CarlaOccDataset

    a, b = CarlaOccDataset(root, voxel_size=VOXEL_SIZE), CarlaOccDataset(directory.root, voxel_size=VOXEL_SIZE)
    assert len(a) == len(b) == CONFIG.scenes.frame_count
    sa, sb = a[1], b[1]
    assert sa.keys() == sb.keys()
    for key in sa:
        if isinstance(sa[key], np.ndarray):
            np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)
