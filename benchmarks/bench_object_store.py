"""The same small build on a directory and on an S3-compatible object store (issue 26).

Starts moto's S3 server on 127.0.0.1 (a thread of this process; nothing leaves the machine),
then builds one sequence of the embedded default (``--frames`` frames at ``--voxel-size`` m, one camera,
one procedural variant per sub-class: every stage) with ``carlaocc run --scheduler synchronous``
in a fresh process, first to a temporary directory and then to ``s3://carlaocc-bench/<run>``,
and prints each build's wall time, the ratio, and the object store's requests by HTTP method
(what the time goes to: moto answers each in milliseconds, a real store in tens of them).

Usage: ``python -m benchmarks.bench_object_store [--frames 2] [--voxel-size 0.4]`` (needs the ``s3``
extra and moto, both in ``.[test]``).
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _build(root: str, config: str, voxel_size: float) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "carlaocc", "run", "--config", config, "--voxel-size", str(voxel_size), "--root", root,
                        "--sequences", "town00_high_seq000", "--scheduler", "synchronous"],
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"the build to {root} failed:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2, help="frames of the sequence")
    ap.add_argument("--voxel-size", "--res", dest="voxel_size", type=float, default=0.4, help="voxel size, m (--res is the short alias)")
    args = ap.parse_args(argv)
    from moto.server import ThreadedMotoServer

    # count the server's requests by method from its access log
    methods: collections.Counter = collections.Counter()

    class Count(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            text = record.getMessage()
            for m in ("GET", "HEAD", "PUT", "POST", "DELETE"):
                if f'"{m} ' in text:
                    methods[m] += 1

    log = logging.getLogger("werkzeug")
    log.setLevel(logging.INFO)
    log.propagate = False
    log.addHandler(Count())
    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    os.environ.update({"AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench", "AWS_DEFAULT_REGION": "us-east-1",
                       "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"})
    try:
        import s3fs

        s3fs.S3FileSystem().mkdir("carlaocc-bench")
        with tempfile.TemporaryDirectory() as tmp:
            config = f"{tmp}/config.json"
            with open(config, "w") as fh:
                json.dump({"ingest": {"variants_per_subclass": 1}, "scenes": {"frame_count": args.frames},
                           "sensors": {"cameras": ["camera_00"]}}, fh)
            directory = _build(f"{tmp}/data", config, args.voxel_size)
            methods.clear()
            s3 = _build(f"s3://carlaocc-bench/{uuid.uuid4().hex[:8]}", config, args.voxel_size)
    finally:
        server.stop()
    print(f"one sequence x {args.frames} frames at {args.voxel_size} m, every stage, synchronous, fresh process each")
    print(f"directory: {directory:.1f} s   loopback S3 (moto): {s3:.1f} s   ratio {s3 / directory:.2f}x")
    print("S3 requests: " + ", ".join(f"{m} {n}" for m, n in methods.most_common()))


if __name__ == "__main__":
    main()
