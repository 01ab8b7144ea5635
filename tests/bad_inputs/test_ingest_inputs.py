"""Bad ingest and voxelize inputs (issue 17, ingest sanity): a mesh with no extent where its class
needs one, an OBJ whose material library or texture is missing, a dataset root inside the folder
being ingested, and a mesh whose faces all have zero area. Meshes are written here as OBJ text.

Each test ingests into its own root next to the shared ``good_root`` and checks that the good
root is byte-identical afterwards."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import assert_clear_error, invoke, snapshot

# a closed 4 x 2 x 1.5 tetrahedron: a plausible car in metres
TETRA = "v 0 0 0\nv 4 0 0\nv 0 2 0\nv 0 0 1.5\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
FLAT_TRIANGLE = "v 0 0 0\nv 4 0 0\nv 0 2 0\nf 1 2 3\n"  # no height


def _ingest(src: Path, cmap: Path, root: Path):
    return invoke("ingest", "folder", src, "--category-map", cmap, "--root", root, "--scheduler", "synchronous")


def _query(root: Path, sql: str) -> list[dict]:
    r = invoke("catalog", "query", sql, "--root", root, "--format", "json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def _source(tmp_path: Path, files: dict[str, str], rows: str) -> tuple[Path, Path]:
    src = tmp_path / "src"
    for rel, text in files.items():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        (src / rel).write_text(text)
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\n" + rows)
    return src, cmap


def test_flat_triangle_as_a_car_is_quarantined_with_reason(good_root, tmp_path):
    before = snapshot(good_root)
    src, cmap = _source(tmp_path, {"flat_car.obj": FLAT_TRIANGLE, "line.obj": FLAT_TRIANGLE},
                        "flat_car.obj,Car,sedan\nline.obj,RoadLine,lane_marking\n")
    root = tmp_path / "root"
    r = _ingest(src, cmap, root)
    assert r.exit_code == 0, r.output  # a bad item is quarantined, never fatal
    assert "Traceback" not in r.output
    assert "library holds 1 assets from it, 1 quarantined (1 flat mesh)" in r.output
    [row] = _query(root, "SELECT source_path, reason, hint FROM quarantine")
    assert row["source_path"].endswith("flat_car.obj") and row["reason"] == "flat mesh"
    assert "no extent along z" in row["hint"] and "Car" in row["hint"]
    # the same triangle is a fine road marking: flat stuff is kept
    [asset] = _query(root, "SELECT category, extent FROM assets")
    assert asset["category"] == "RoadLine" and asset["extent"][2] == 0.0
    assert snapshot(good_root) == before


def test_a_car_far_too_thin_is_quarantined(good_root, tmp_path):
    before = snapshot(good_root)
    thin = TETRA.replace("v 0 0 1.5", "v 0 0 0.02")  # 2 cm high
    src, cmap = _source(tmp_path, {"decal.obj": thin}, "*.obj,Car,sedan\n")
    root = tmp_path / "root"
    r = _ingest(src, cmap, root)
    assert r.exit_code == 0 and "1 quarantined (1 too thin)" in r.output, r.output
    [row] = _query(root, "SELECT reason, hint FROM quarantine")
    assert row["reason"] == "too thin" and "z below 0.175 m" in row["hint"]
    assert snapshot(good_root) == before


def test_obj_with_missing_mtl_or_texture_is_ingested_with_a_note(good_root, tmp_path):
    before = snapshot(good_root)
    src, cmap = _source(tmp_path, {
        "no_mtl.obj": "mtllib no_mtl.mtl\nusemtl paint\n" + TETRA,
        "no_tex.obj": "mtllib no_tex.mtl\nusemtl paint\n" + TETRA.replace("v 4 0 0", "v 4.2 0 0"),
        "no_tex.mtl": "newmtl paint\nKd 1 0 0\nmap_Kd textures/paint.png\n",
        "fine.obj": TETRA.replace("v 4 0 0", "v 4.4 0 0"),
    }, "*.obj,Car,sedan\n")
    root = tmp_path / "root"
    r = _ingest(src, cmap, root)
    assert r.exit_code == 0 and "library holds 3 assets from it, 0 quarantined" in r.output, r.output
    rows = _query(root, "SELECT source_path, notes FROM assets WHERE notes LIKE '%not found%' ORDER BY source_path")
    got = {Path(row["source_path"]).name: row["notes"] for row in rows}
    assert set(got) == {"no_mtl.obj", "no_tex.obj"}
    assert "material library 'no_mtl.mtl' not found" in got["no_mtl.obj"]
    assert "texture 'textures/paint.png' not found" in got["no_tex.obj"]
    assert snapshot(good_root) == before


def test_dataset_root_inside_the_source_is_skipped(good_root, tmp_path):
    before = snapshot(good_root)
    src, cmap = _source(tmp_path, {"car.obj": TETRA}, "*,Car,sedan\n")
    root = src / "data"  # the dataset root inside the folder being ingested
    for _ in range(2):  # the second run finds admesh/meshes/*.glb under the root: still skipped
        r = _ingest(src, cmap, root)
        assert r.exit_code == 0, r.output
        assert f"{src}: 1 items" in r.output and "0 quarantined" in r.output, r.output
        notes = [ln for ln in r.output.splitlines() if "skipped the dataset root" in ln]
        assert len(notes) == 1 and str(root) in notes[0]
        assert r.output.count("skipped the dataset root") == 1  # printed once
    assert list((root / "admesh" / "meshes").glob("*.glb"))  # the root holds meshes that were not re-read
    [asset] = _query(root, "SELECT source_path FROM assets")
    assert asset["source_path"] == str(src / "car.obj")
    assert snapshot(good_root) == before


def test_a_source_elsewhere_says_nothing_about_skipping(tmp_path):
    src, cmap = _source(tmp_path, {"car.obj": TETRA}, "*,Car,sedan\n")
    r = _ingest(src, cmap, tmp_path / "root")
    assert r.exit_code == 0 and "dataset root" not in r.output, r.output


def test_voxelize_a_mesh_whose_faces_all_have_zero_area_is_an_error(good_root, tmp_path):
    before = snapshot(good_root)
    mesh = tmp_path / "needles.obj"  # a collinear triangle and one with a repeated corner
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 4 4\n")
    out = tmp_path / "out.npz"
    r = invoke("voxelize", mesh, "--voxel-size", "0.1", "--class", "Car", "--out", out)
    line = assert_clear_error(r, 2, str(mesh))
    assert "zero area" in line
    assert not out.exists()
    # with one real triangle it voxelizes
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n")
    r = invoke("voxelize", mesh, "--voxel-size", "0.1", "--class", "Car", "--out", out)
    assert r.exit_code == 0 and out.exists(), r.output
    assert snapshot(good_root) == before
