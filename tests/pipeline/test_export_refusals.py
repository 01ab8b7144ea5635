"""An export that refuses (exit 2) writes nothing: the target folder is exactly as before --
absent, or an earlier export's files byte-identical -- and no staging folder is left beside it.
One refusal per format family on the shared built root (0.1 m, two frames a sequence): an
unknown sequence, a voxel size not built, and refusals found only after files were staged (a
release sequence without a pose, after the sequences before it were written)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app

cli = CliRunner()


def snapshot(folder: Path) -> dict[str, bytes] | None:
    """Every file under ``folder`` with its bytes (None: no folder)."""
    if not folder.exists():
        return None
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def assert_untouched(out: Path, before) -> None:
    assert snapshot(out) == before
    assert not [p.name for p in out.parent.iterdir() if ".export-" in p.name], "a staging folder was left behind"


def export(fmt: str, root: str, out: Path, *args: str):
    return cli.invoke(app, ["export", fmt, "--root", root, "--out", str(out), *args])


@pytest.mark.parametrize("fmt", ["occ3d", "semantickitti", "sscbench-kitti360", "surroundocc", "carlaocc-npz",
                                 "carlaocc-release", "mmdet3d-infos", "openocc-v2", "uniocc", "det-gt"])
def test_a_refused_export_writes_nothing(default_01, tmp_path, fmt):
    # into a folder not there yet: an unknown sequence, a voxel size not built
    out = tmp_path / "new" / "out"
    for args in (["--res", "0.1", "--sequence", "nowhere_seq000"], ["--res", "0.3"]):
        r = export(fmt, default_01.url, out, *args)
        assert r.exit_code == 2, r.output
        assert not (tmp_path / "new").exists()
    # into a folder with other files: they stay byte-identical
    out = tmp_path / "kept"
    (out / "gts").mkdir(parents=True)
    (out / "grid.json").write_text('{"earlier": true}\n')
    (out / "gts" / "notes.txt").write_bytes(b"\x00mine")
    before = snapshot(out)
    r = export(fmt, default_01.url, out, "--res", "0.1", "--sequence", "nowhere_seq000")
    assert r.exit_code == 2, r.output
    assert_untouched(out, before)


def test_a_release_refused_after_staging_files_leaves_the_earlier_export_as_it_was(default_01, tmp_path):
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import FrameRecord

    root = tmp_path / "data"
    shutil.copytree(default_01.root, root)
    store = Store(str(root))
    seqs = [s for (s,) in query(store, "SELECT sequence_id FROM sequences ORDER BY sequence_id")[1]]
    out = tmp_path / "CarlaOcc"
    # an earlier export of the first sequence is there
    r = export("carlaocc-release", str(root), out, "--sequence", seqs[0])
    assert r.exit_code == 0, r.output
    before = snapshot(out)
    # the last sequence lost a pose: found only after the sequences before it were staged
    frames = ParquetTable(store, FrameRecord)
    frames.save(seqs[-1], [f for f in frames.load([seqs[-1]]) if f.frame_index != 1])
    r = export("carlaocc-release", str(root), out)
    assert r.exit_code == 2 and f"{seqs[-1]}: no LiDAR pose for frame 1" in r.output
    assert_untouched(out, before)
    # into a new folder: nothing at all (before: Town.._Seq../poses/lidar.txt and the grids of the earlier sequences)
    fresh = tmp_path / "fresh"
    assert export("carlaocc-release", str(root), fresh).exit_code == 2
    assert_untouched(fresh, None)
    # the refusal did not break adding sequences: the others export into the earlier folder
    r = export("carlaocc-release", str(root), out, "--sequence", seqs[1])
    assert r.exit_code == 0, r.output
    after = snapshot(out)
    assert set(before) < set(after) and all(after[k] == v for k, v in before.items() if "splits" not in k
                                            and not k.endswith(".json"))
