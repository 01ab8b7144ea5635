"""Bad inputs of the command line itself, all through the one error path: scheduler addresses
(malformed, unreachable), OpenDRIVE towns a config references (no roads, no driving lanes, no
drivable cycle), category maps, option values (``--origin``), dataset roots that are missing or
a file; unexpected exceptions (one line, exit 1, a hint at ``--debug``), ``--debug`` itself, and
a LocalCluster's teardown that prints nothing after a successful run."""

from __future__ import annotations

import importlib
import math
import socket
import subprocess
import sys
import textwrap

import pytest

from conftest import assert_clear_error, invoke, snapshot

import carlaocc.pipeline.cli as cli_pkg
from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.engine import runner
from carlaocc.pipeline.cli.common import DEBUG_ENV

TETRA = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"


@pytest.fixture(autouse=True)
def _no_env(monkeypatch):
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    monkeypatch.delenv(DEBUG_ENV, raising=False)


def _refused_port() -> int:
    """A local port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ------------------------------------------------------------------ scheduler addresses


@pytest.mark.parametrize("address, why", [
    ("tcp://127.0.0.1:", "no port"),
    ("tcp://127.0.0.1:70000", "70000"),
    ("tcp://127.0.0.1:0", "not in 1..65535"),
    ("tcp://127.0.0.1:http", "not a number"),
    ("tcp://:8786", "no host"),
    ("tcp://127.0.0.1", "no port"),
    ("127.0.0.1:8786", "not a Dask scheduler address"),
])
def test_malformed_scheduler_is_refused_up_front(good_root, address, why):
    before = snapshot(good_root)
    r = invoke("run", "--scheduler", address, "--root", good_root)
    line = assert_clear_error(r, 2, "--scheduler", address)
    assert why in line
    r = invoke("ingest", "folder", good_root, "--scheduler", address, "--root", good_root)
    assert_clear_error(r, 2, "--scheduler", address)
    assert snapshot(good_root) == before


def test_malformed_scheduler_from_the_environment_names_the_variable(good_root, monkeypatch):
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:99999")
    before = snapshot(good_root)
    assert_clear_error(invoke("run", "--root", good_root), 2, "DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:99999")
    assert snapshot(good_root) == before


def test_unreachable_scheduler_fails_at_once_naming_it(good_root, tmp_path):
    address = f"tcp://127.0.0.1:{_refused_port()}"
    before = snapshot(good_root)
    line = assert_clear_error(invoke("run", "--scheduler", address, "--root", good_root), 2, "--scheduler", address)
    assert "cannot reach" in line
    new = tmp_path / "new-root"
    assert_clear_error(invoke("run", "--scheduler", address, "--root", new), 2, address)
    assert not new.exists()
    assert snapshot(good_root) == before


def test_executor_probes_before_the_client():
    """The Python API (no CLI) fails as fast: the executor's TCP probe, not a 30 s Client timeout."""
    address = f"tcp://127.0.0.1:{_refused_port()}"
    with pytest.raises(runner.PlanError, match=address.replace(".", r"\.")):
        runner.DaskExecutor(address, processes=True)._get_client()


@pytest.mark.parametrize("address, host_port", [
    ("tcp://127.0.0.1:8786", ("127.0.0.1", 8786)),
    ("tcp://[::1]:65535", ("::1", 65535)),
    ("tls://scheduler.example:1", ("scheduler.example", 1)),
    ("inproc://10.0.0.1/1234/1", None),
])
def test_well_formed_addresses(address, host_port):
    assert runner.DaskExecutor.host_port(address) == host_port
    assert runner.resolve_scheduler(address) == address


# ------------------------------------------------------------------ OpenDRIVE towns


def _stadium(driving: str = "driving", closed: bool = True) -> str:
    """A one-road oval (two straights, two half circles) whose lane is its own successor."""
    r = 30.0
    succ = '<successor elementType="road" elementId="7" contactPoint="start"/>' if closed else ""
    sections = "".join(f'''<laneSection s="{s0}">
   <left><lane id="1" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></left>
   <center><lane id="0" type="none"/></center>
   <right><lane id="-1" type="{driving}"><link><predecessor id="-1"/><successor id="-1"/></link>
     <width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
  </laneSection>''' for s0 in (0, 100))
    return f"""<OpenDRIVE><header revMajor="1" revMinor="4"/>
<road id="7" length="{200 + 2 * math.pi * r!r}" junction="-1">
 <link><predecessor elementType="road" elementId="7" contactPoint="end"/>{succ}</link>
 <planView>
  <geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>
  <geometry s="100" x="100" y="0" hdg="0" length="{math.pi * r!r}"><arc curvature="{1 / r!r}"/></geometry>
  <geometry s="{100 + math.pi * r!r}" x="100" y="{2 * r!r}" hdg="{math.pi!r}" length="100"><line/></geometry>
  <geometry s="{200 + math.pi * r!r}" x="0" y="{2 * r!r}" hdg="{math.pi!r}" length="{math.pi * r!r}"><arc curvature="{1 / r!r}"/></geometry>
 </planView>
 <lanes>{sections}</lanes>
</road></OpenDRIVE>"""


@pytest.mark.parametrize("name, text, why", [
    ("noroads.xodr", '<OpenDRIVE><header revMajor="1" revMinor="4"/></OpenDRIVE>', "no roads"),
    ("nodriving.xodr", _stadium(driving="sidewalk"), "no driving lanes"),
    ("deadend.xodr", _stadium(closed=False), "no cycle"),
    ("broken.xodr", "<OpenDRIVE><road", ""),
])
def test_opendrive_town_the_scenes_stage_cannot_drive_is_refused_up_front(good_root, tmp_path, name, text, why):
    xodr = tmp_path / name
    xodr.write_text(text)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"scenes:\n  towns:\n    - style: opendrive\n      opendrive: {xodr}\n")
    before = snapshot(good_root)
    line = assert_clear_error(invoke("run", "--config", cfg, "--root", good_root), 2, str(xodr))
    assert why in line
    assert_clear_error(invoke("status", "--config", cfg, "--root", good_root), 2, str(xodr))
    assert snapshot(good_root) == before


def test_a_drivable_opendrive_town_passes_the_check(tmp_path):
    from carlaocc.pipeline.cli.common import check_towns
    from carlaocc.schemas.configs import DatasetConfig

    xodr = tmp_path / "stadium.xodr"
    xodr.write_text(_stadium())
    check_towns(DatasetConfig.model_validate({"scenes": {"towns": [{"style": "opendrive", "opendrive": str(xodr)}]}}))
    check_towns(DatasetConfig())  # the embedded default's built-in town


@pytest.mark.parametrize("kind, why", [("directory", "is a directory"), ("binary", "cannot read"),
                                       ("missing", "does not exist")])
def test_unreadable_config_file(good_root, tmp_path, kind, why):
    cfg = tmp_path / "c.yaml"
    if kind == "directory":
        cfg.mkdir()
    elif kind == "binary":
        cfg.write_bytes(b"\xff\xfe\x00scenes")
    before = snapshot(good_root)
    line = assert_clear_error(invoke("run", "--config", cfg, "--root", good_root), 2, "--config", str(cfg))
    assert why in line
    assert snapshot(good_root) == before


# ------------------------------------------------------------------ category maps


@pytest.mark.parametrize("kind, why", [
    ("missing", "does not exist"),
    ("directory", "is a directory"),
    ("unknown-class", "Carr"),
    ("no-columns", "lacks column"),
])
def test_bad_category_map_is_refused_up_front(good_root, tmp_path, kind, why):
    src = tmp_path / "src"
    src.mkdir()
    (src / "car.obj").write_text(TETRA)
    cmap = tmp_path / "map.csv"
    if kind == "directory":
        cmap.mkdir()
    elif kind == "unknown-class":
        cmap.write_text("glob,category,subclass\n*.obj,Carr,sedan\n")
    elif kind == "no-columns":
        cmap.write_text("foo,bar\n1,2\n")
    before = snapshot(good_root)
    r = invoke("ingest", "folder", src, "--category-map", cmap, "--root", good_root, "--scheduler", "synchronous")
    line = assert_clear_error(r, 2, "map.csv")
    assert why in line
    assert snapshot(good_root) == before


# ------------------------------------------------------------------ option values


@pytest.mark.parametrize("args, option", [
    (["--origin", "nan,0,0", "--shape", "2,2,2"], "--origin"),
    (["--origin", "inf,0,0", "--shape", "2,2,2"], "--origin"),
    (["--origin", "1,2", "--shape", "2,2,2"], "--origin"),
    (["--origin", "0,0,0", "--shape", "1.5,2,2"], "--shape"),
    (["--origin", "0,0,0", "--shape", "0,2,2"], "--shape"),
    (["--origin", "0,0,0"], "--shape"),
])
def test_voxelize_grid_options_are_one_line_naming_the_option(tmp_path, args, option):
    mesh = tmp_path / "t.obj"
    mesh.write_text(TETRA)
    out = tmp_path / "o.npz"
    r = invoke("voxelize", mesh, "--class", "Car", "--voxel-size", "0.2", "--out", out, *args)
    line = assert_clear_error(r, 2, option)
    assert "validation error" not in line and "pydantic" not in line
    assert not out.exists()


def test_pydantic_errors_escaping_a_command_are_one_line(good_root, monkeypatch):
    from pydantic import BaseModel

    class Grid(BaseModel):
        size: int

    def boom(*a, **k):
        Grid(size="big")

    monkeypatch.setattr(runner, "status", boom)
    line = assert_clear_error(invoke("status", "--root", good_root), 2, "size")
    assert "errors.pydantic.dev" not in line


# ------------------------------------------------------------------ dataset roots


@pytest.mark.parametrize("command", [
    ["catalog", "query", "SELECT count(*) FROM assets"],
    ["status"],
    ["export", "occ3d", "--res", "0.2", "--out", "{tmp}/out"],
    ["show", "occupancy", "--seq", "x", "--frame", "0", "--res", "0.2", "--out", "{tmp}/o.png"],
    ["admesh", "sheet", "--out", "{tmp}/s.png"],
])
@pytest.mark.parametrize("what", ["missing", "file"])
def test_reading_a_root_that_is_not_a_dataset_is_an_error(tmp_path, command, what):
    root = tmp_path / "nope"
    if what == "file":
        root.write_text("x")
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    line = assert_clear_error(invoke(*args, "--root", root), 2, "--root", str(root))
    assert ("does not exist" if what == "missing" else "is a file") in line
    assert root.exists() == (what == "file")
    assert not (tmp_path / "out").exists()


def test_query_on_a_good_root_still_answers(good_root):
    before = snapshot(good_root)
    r = invoke("catalog", "query", "SELECT count(*) AS n FROM assets", "--root", good_root, "--format", "csv")
    assert r.exit_code == 0, r.output
    assert int(r.output.splitlines()[1]) > 0
    assert snapshot(good_root) == before


# ------------------------------------------------------------------ the error path itself


def test_unexpected_exception_is_one_line_with_a_debug_hint(good_root, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("the flux capacitor\nis empty")

    monkeypatch.setattr(runner, "status", boom)
    line = assert_clear_error(invoke("status", "--root", good_root), 1, "RuntimeError", "flux capacitor", "--debug")
    assert "is empty" in line  # a multi-line message keeps its content on the one line


def test_failure_during_work_exits_1(good_root, monkeypatch):
    def broken(*a, **k):
        raise StoreError(f"{good_root}/catalog/runs: disk on fire")

    monkeypatch.setattr(runner, "run", broken)
    before = snapshot(good_root)
    assert_clear_error(invoke("run", "--root", good_root, "--scheduler", "synchronous"), 1, "disk on fire")
    assert snapshot(good_root) == before


@pytest.mark.parametrize("how", ["option", "env"])
def test_debug_shows_the_traceback(good_root, monkeypatch, how):
    if how == "env":
        monkeypatch.setenv(DEBUG_ENV, "1")
        args = ["run", "--scheduler", "tcp://127.0.0.1:", "--root", good_root]
    else:
        args = ["--debug", "run", "--scheduler", "tcp://127.0.0.1:", "--root", good_root]
    r = invoke(*args)
    assert r.exit_code == 2, r.output
    assert "Traceback" in r.output and "PlanError" in r.output
    assert [ln for ln in r.output.splitlines() if ln.startswith("error:")][-1].startswith("error: --scheduler")

    def boom(*a, **k):
        raise RuntimeError("kaboom")

    monkeypatch.setattr(runner, "status", boom)
    r = invoke("--debug", "status", "--root", good_root)
    assert r.exit_code == 1 and "Traceback" in r.output and "kaboom" in r.output
    # and without it, the same error is one line again
    monkeypatch.delenv(DEBUG_ENV, raising=False)
    assert_clear_error(invoke("status", "--root", good_root), 1, "kaboom")


def test_main_is_the_last_net(monkeypatch, capsys):
    def broken_app():
        raise MemoryError("out of memory while starting")

    # the Typer application main runs is the attribute of the module carlaocc.pipeline.cli.app (the
    # package's own `app` is a lazy view of it: see COMMAND_MODULES)
    monkeypatch.setattr(importlib.import_module("carlaocc.pipeline.cli.app"), "app", broken_app)
    monkeypatch.setattr(sys, "argv", ["carlaocc", "status"])
    # main leaves the process with os._exit (tests/pipeline/test_exit.py runs that for real): here,
    # an ordinary SystemExit, so the test process lives on
    monkeypatch.setattr(cli_pkg, "leave", sys.exit)
    with pytest.raises(SystemExit) as exit_info:
        cli_pkg.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "MemoryError" in lines[0] and "--debug" in lines[0]


# ------------------------------------------------------------------ quiet teardown


def test_local_cluster_teardown_prints_nothing(tmp_path):
    """A tiny run on our own LocalCluster, twice in a fresh process: stderr stays free of
    the workers' heartbeat tracebacks (CommClosedError) as the cluster shuts down."""
    (tmp_path / "tiny_task.py").write_text("def task(store, cfg, part):\n    return {}\n")
    script = tmp_path / "tiny_run.py"
    script.write_text(textwrap.dedent("""
        import sys


        def main():
            from carlaocc.catalog.store import Store
            from carlaocc.pipeline.engine import runner
            from carlaocc.pipeline.engine.spec import Partition, StageSpec
            from carlaocc.schemas.configs import DatasetConfig
            import tiny_task

            registry = {"ingest": StageSpec("ingest", "tiny", (), (), (),
                                            lambda ctx: [Partition(f"p{i}") for i in range(4)], tiny_task.task)}
            out = runner.run(Store(sys.argv[1]), DatasetConfig(), (0.2,), force=True, workers=2, registry=registry)
            assert not out[0].failed and out[0].ran == 4, out
            print("ok")


        if __name__ == "__main__":
            main()
    """))
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    for i in range(2):
        p = subprocess.run([sys.executable, str(script), str(tmp_path / "root")], capture_output=True, text=True,
                           env=env, timeout=300)
        assert p.returncode == 0 and p.stdout.strip() == "ok", p.stdout + p.stderr
        for bad in ("Traceback", "CommClosedError", "Port 8787"):
            assert bad not in p.stderr, f"run {i}: {bad} on stderr:\n{p.stderr}"
