"""Ingest throughput: assets per second for the procedural and the folder sources, at 1 and 2
workers (LocalCluster processes), each into a fresh store, in one run.

The folder source is a directory of procedural assets exported as GLB files (so it exercises
reading, standardization and validation of real files) with a category map.
Usage: ``python -m benchmarks.bench_ingest [N_FILES]`` (default 200).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path


def _folder_source(n: int, where: Path) -> Path:
    import trimesh

    from carlaocc.schemas.configs import IngestConfig
    from carlaocc.stages.ingest.procedural import ingest_procedural

    lib = ingest_procedural(IngestConfig())
    src = where / "src"
    rows = ["glob,category,subclass"]
    for i in range(n):
        a = lib.assets[i % len(lib.assets)]
        scene = trimesh.Scene()
        for k, p in enumerate(lib.geometry[a.asset_id].parts):
            # a different jitter per copy so every file is a distinct asset
            v = p.vertices * (1.0 + 0.001 * (i // len(lib.assets)))
            scene.add_geometry(trimesh.Trimesh(v[:, [0, 2, 1]] * [1, 1, -1], p.faces, process=False), geom_name=f"p{k}")
        d = src / a.category
        d.mkdir(parents=True, exist_ok=True)
        (d / f"{i:04d}.glb").write_bytes(scene.export(file_type="glb"))
        rows.append(f"{a.category}/{i:04d}.glb,{a.category},{a.subclass}")
    (where / "map.csv").write_text("\n".join(rows) + "\n")
    return src


def main(argv: list[str] | None = None) -> None:
    from typer.testing import CliRunner

    from carlaocc.pipeline.cli import app

    n = int((argv or ["200"])[0])
    tmp = Path(tempfile.mkdtemp(prefix="carlaocc-bench-ingest-"))
    try:
        src = _folder_source(n, tmp)
        cli = CliRunner()
        print(f"{'source':<11}{'workers':>8}{'assets':>8}{'seconds':>9}{'assets/s':>10}")
        for workers in (1, 2):
            root = tmp / f"proc{workers}"
            t0 = time.perf_counter()
            r = cli.invoke(app, ["run", "--stages", "ingest", "--root", str(root), "--workers", str(workers)])
            dt = time.perf_counter() - t0
            assert r.exit_code == 0, r.output
            from carlaocc.catalog.sql import query
            from carlaocc.catalog.store import Store

            count = query(Store(str(root)), "SELECT count(*) FROM assets")[1][0][0]
            print(f"{'procedural':<11}{workers:>8}{count:>8}{dt:>9.2f}{count / dt:>10.1f}")
        for workers in (1, 2):
            root = tmp / f"folder{workers}"
            t0 = time.perf_counter()
            r = cli.invoke(app, ["ingest", "folder", str(src), "--category-map", str(tmp / "map.csv"),
                                 "--root", str(root), "--workers", str(workers)])
            dt = time.perf_counter() - t0
            assert r.exit_code == 0, r.output
            count = query(Store(str(root)), "SELECT count(*) FROM assets")[1][0][0]
            print(f"{'folder':<11}{workers:>8}{count:>8}{dt:>9.2f}{count / dt:>10.1f}")
        print("(wall time of the whole command: cluster start, listing, tasks, lineage)")
    finally:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main(sys.argv[1:])
