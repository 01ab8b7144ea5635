"""``carlaocc voxelize``: the standalone voxelizer on mesh files (and its errors)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from carlaocc.catalog.voxel_file import load_voxels
from carlaocc.pipeline.cli import app
from shared_data import require, shared_path

cli = CliRunner()
MODELS = shared_path("meshes/trimesh-models")


@pytest.fixture
def cube_obj(tmp_path) -> Path:
    path = tmp_path / "cube.obj"
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(path)
    return path


def test_cube_known_answer_filled_and_surface(tmp_path, cube_obj):
    args = ["voxelize", str(cube_obj), "--class", "Car", "--voxel-size", "0.1",
            "--origin", "-0.55,-0.55,-0.55", "--shape", "13,13,13"]
    r = cli.invoke(app, [*args, "--out", str(tmp_path / "solid.npz")])
    assert r.exit_code == 0, r.output
    semantic, instance = load_voxels(tmp_path / "solid.npz").dense()
    assert semantic.shape == (13, 13, 13) and np.count_nonzero(semantic) == 1331
    assert set(np.unique(instance)) == {0, 1}
    np.testing.assert_allclose(np.load(tmp_path / "solid.npz")["voxel_origin"], (-0.55, -0.55, -0.55))
    r = cli.invoke(app, [*args, "--fill", "surface", "--out", str(tmp_path / "shell.zarr")])
    assert r.exit_code == 0, r.output
    import zarr

    g = zarr.open_group(str(tmp_path / "shell.zarr"), mode="r")
    assert np.count_nonzero(g["semantic"][...]) == 602
    assert g["semantic"].attrs["voxel_size"] == 0.1


def test_per_file_classes_and_default_grid(tmp_path, cube_obj):
    require(MODELS / "chair_model.obj")
    out = tmp_path / "two.npz"
    r = cli.invoke(app, ["voxelize", str(cube_obj), str(MODELS / "chair_model.obj"), "--class", "Car",
                         "--class", "Sidewalk", "--voxel-size", "0.05", "--out", str(out)])
    assert r.exit_code == 0, r.output
    semantic, instance = load_voxels(out).dense()
    from carlaocc.schemas import taxonomy

    car, walk = taxonomy.by_name("Car").id, taxonomy.by_name("Sidewalk").id
    assert {car, walk} <= set(np.unique(semantic))
    assert (instance[semantic == walk] == 0).all()  # stuff: instance 0
    # the default grid is the bounding box snapped to the 0.05 m lattice
    origin = np.load(out)["voxel_origin"]
    assert np.allclose(origin / 0.05, np.round(origin / 0.05))


@pytest.mark.parametrize("args, message", [
    (["missing.obj", "--class", "Car"], "missing.obj: no such file"),
    (["{cube}"], "give --class"),
    (["{cube}", "--class", "Spaceship"], "unknown semantic class"),
    (["{cube}", "--class", "Car", "--fill", "hollow"], "--fill must be one of"),
    (["{cube}", "--class", "Car", "--origin", "0,0"], "--origin must be three"),
    (["{cube}", "--class", "Car", "--origin", "0,0,0"], "together"),
])
def test_errors_name_the_input(tmp_path, cube_obj, args, message):
    args = [a.replace("{cube}", str(cube_obj)) for a in args]
    r = cli.invoke(app, ["voxelize", *args, "--voxel-size", "0.1", "--out", str(tmp_path / "x.npz")])
    assert r.exit_code == 2 and message in r.output, r.output
    assert not (tmp_path / "x.npz").exists()


def test_wrong_units_and_corrupt_mesh(tmp_path, cube_obj):
    big = tmp_path / "mm.obj"
    m = trimesh.creation.box(extents=(4000.0, 2000.0, 1500.0))  # a car in millimetres
    m.export(big)
    r = cli.invoke(app, ["voxelize", str(big), "--class", "Car", "--voxel-size", "0.05", "--out", str(tmp_path / "x.npz")])
    assert r.exit_code == 2 and "millimetres" in r.output
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    r = cli.invoke(app, ["voxelize", str(bad), "--class", "Car", "--voxel-size", "0.1", "--out", str(tmp_path / "x.npz")])
    assert r.exit_code == 2 and "bad.obj" in r.output, r.output


def test_sparse_npz_holds_the_dense_layouts_voxels(tmp_path, cube_obj):
    """The default npz (occupied voxels) against --dense (the layout before format 1) and the
    dense voxelization itself, with a thing, stuff, a fill and a default grid."""
    require(MODELS / "chair_model.obj")
    args = ["voxelize", str(cube_obj), str(MODELS / "chair_model.obj"), "--class", "Car", "--class", "Building",
            "--voxel-size", "0.05"]
    assert cli.invoke(app, [*args, "--out", str(tmp_path / "sparse.npz")]).exit_code == 0
    r = cli.invoke(app, [*args, "--dense", "--out", str(tmp_path / "dense.npz")])
    assert r.exit_code == 0, r.output
    d = np.load(tmp_path / "dense.npz")
    assert set(d.files) == {"semantic", "instance", "voxel_size", "voxel_origin", "shape"}
    semantic, instance = load_voxels(tmp_path / "sparse.npz").dense()
    np.testing.assert_array_equal(semantic, d["semantic"])
    np.testing.assert_array_equal(instance, d["instance"])
    from carlaocc.pipeline.commands.standalone import grid_for, load_inputs
    from carlaocc.stages.voxelize import voxelize_scene

    meshes = load_inputs([str(cube_obj), str(MODELS / "chair_model.obj")], ["Car", "Building"])
    want_semantic, want_instance = voxelize_scene(meshes, grid_for(meshes, 0.05))
    np.testing.assert_array_equal(semantic, want_semantic)
    np.testing.assert_array_equal(instance, want_instance)
    assert np.count_nonzero(instance) > 0 and np.count_nonzero(semantic) > np.count_nonzero(instance)


def test_dense_is_refused_for_zarr(tmp_path, cube_obj):
    r = cli.invoke(app, ["voxelize", str(cube_obj), "--class", "Car", "--voxel-size", "0.1", "--dense",
                         "--out", str(tmp_path / "x.zarr")])
    assert r.exit_code == 2 and "--dense is a layout of OUT.npz" in r.output, r.output
    assert not (tmp_path / "x.zarr").exists()


def test_a_surface_run_imports_only_what_it_uses(tmp_path):
    """A binary PLY voxelized as a surface needs neither trimesh (the PLY is read with numpy) nor
    scipy's flood fill, Zarr, Dask or Arrow: checked in a fresh interpreter, by module."""
    import json
    import subprocess
    import sys

    ply = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(ply)
    code = ("import sys, json\nfrom carlaocc.pipeline.cli import app\n"
            f"app(['voxelize', {str(ply)!r}, '--class', 'Road', '--voxel-size', '0.1', '--out', "
            f"{str(tmp_path / 'x.npz')!r}], standalone_mode=False)\n"
            "print(json.dumps(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert "numba" in loaded and (tmp_path / "x.npz").exists()  # the check sees what it ran
    assert not loaded & {"trimesh", "zarr", "scipy.ndimage", "dask", "distributed", "pyarrow"}, sorted(
        loaded & {"trimesh", "zarr", "scipy.ndimage", "dask", "distributed", "pyarrow"})


def test_the_threads_wait_asleep_unless_the_user_chose(tmp_path, cube_obj, monkeypatch):
    # numba's OpenMP threads must not spin while waiting (CPU burnt on a busy machine); a wait
    # policy the user set is kept
    args = ["voxelize", str(cube_obj), "--class", "Car", "--voxel-size", "0.25", "--out", str(tmp_path / "c.npz")]
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    assert cli.invoke(app, args).exit_code == 0
    import os

    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    assert cli.invoke(app, args).exit_code == 0
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
