"""The one grid.json / split-list writer every export uses (catalog/formats/manifest.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats.manifest import INDEX_TO_METRE, grid_manifest, save_grid_manifest, save_split_lists


def test_one_grid_inline_and_its_index_to_metre_rule(tmp_path):
    doc = grid_manifest("occ3d", "ego", [{"origin": (-40.0, -40.0, -1.0), "voxel_size": 0.4, "shape": (200, 200, 16)}],
                        ["a", "b"], 17, "release", notes={"flow": "m/s"})
    assert list(doc) == ["format", "frame", "origin", "voxel_size", "shape", "axis_order", "index_to_metre", "labels",
                         "free_label", "built_from_label_table", "flow"]
    assert doc["frame"] == "ego (x forward, y left, z up)" and doc["index_to_metre"] == INDEX_TO_METRE
    assert save_grid_manifest(tmp_path, doc) == 1
    back = json.loads((tmp_path / "grid.json").read_text())
    assert back == {**doc, "origin": [-40.0, -40.0, -1.0], "shape": [200, 200, 16]}
    # the rule as written: index (0, 0, 0) has its centre half a voxel inside the origin
    centre = np.asarray(back["origin"]) + (np.zeros(3) + 0.5) * back["voxel_size"]
    assert np.allclose(centre, [-39.8, -39.8, -0.8])


def test_several_grids_are_listed_with_their_folders():
    grids = [{"folder": "vs_0_1", "voxel_size": 0.1, "origin": (0.0, -25.6, -2.0), "shape": (512, 512, 64)},
             {"folder": "vs_0_4", "voxel_size": 0.4, "origin": (-40.0, -40.0, -2.0), "shape": (200, 200, 16)}]
    doc = grid_manifest("carlaocc-release", "lidar", grids, ["x"], 0, "release", encoding="bits")
    assert "origin" not in doc and [g["folder"] for g in doc["grids"]] == ["vs_0_1", "vs_0_4"]
    assert doc["label_encoding"] == "bits" and doc["grids"][1]["origin"] == [-40.0, -40.0, -2.0]


def test_split_lists_one_line_each(tmp_path):
    assert save_split_lists(tmp_path, {"train": ["a", "b"], "val": [], "test": ["c"]}) == 3
    assert (tmp_path / "splits" / "train.txt").read_text() == "a\nb\n"
    assert (tmp_path / "splits" / "val.txt").read_text() == ""
    assert not [p for p in (tmp_path / "splits").iterdir() if p.name.startswith(".")]  # no partial files left


def test_a_file_deep_in_an_export_finds_its_grid(tmp_path):
    import pytest

    from carlaocc.catalog.formats.manifest import find_grid_manifest, grid_of

    one = grid_manifest("occ3d", "ego", [{"origin": [-40, -40, -1], "voxel_size": 0.4, "shape": [200, 200, 16]}],
                        ["a", "free"], 1, "release")
    save_grid_manifest(tmp_path / "one", one)
    f = tmp_path / "one" / "gts" / "s" / "t" / "labels.npz"
    doc, folder = find_grid_manifest(f)
    assert folder == (tmp_path / "one").resolve()
    assert grid_of(doc, f.resolve().relative_to(folder)) == {"origin": (-40.0, -40.0, -1.0), "voxel_size": 0.4,
                                                             "shape": (200, 200, 16), "frame": "ego"}
    # a grid per folder: the file's folder picks it
    many = grid_manifest("carlaocc-release", "lidar", [
        {"folder": "vs_0_1", "origin": [-25.6, -25.6, -3.0], "voxel_size": 0.1, "shape": [768, 512, 130]},
        {"folder": "vs_0_4", "origin": [-25.6, -25.6, -2.4], "voxel_size": 0.4, "shape": [128, 128, 16]}],
        ["a"], 0, "release")
    save_grid_manifest(tmp_path / "many", many)
    g = grid_of(find_grid_manifest(tmp_path / "many" / "Seq" / "occupancy" / "vs_0_4" / "0000.npz")[0],
                Path("Seq/occupancy/vs_0_4/0000.npz"))
    assert g["voxel_size"] == 0.4 and g["shape"] == (128, 128, 16) and g["frame"] == "lidar"
    with pytest.raises(ValueError, match="vs_0_2"):
        grid_of(many, Path("Seq/occupancy/vs_0_2/0000.npz"))
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "grid.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="not a grid.json"):
        find_grid_manifest(tmp_path / "bad" / "x.npz")
