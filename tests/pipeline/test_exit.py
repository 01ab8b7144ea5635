"""The exit code is the command's, whatever native or Python threads are still alive when it ends
(``carlaocc.pipeline.cli.exit``): the entry point runs the atexit handlers, flushes, and leaves
without the interpreter's teardown, where a still-joinable native thread pool aborts the process
(SIGABRT, exit 134) after a success. Checked in fresh interpreters, by exit code and output."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from tests.shared_data import shared_path

# a thread still alive at exit: non-daemon and blocked, so an ordinary interpreter exit would wait
# for it forever (the subprocess timeout below turns that into a failure, never a hang)
SCRIPT = textwrap.dedent("""
    import atexit, sys, threading
    from carlaocc.pipeline.cli import main
    from carlaocc.stages.threads import set_kernel_threads

    set_kernel_threads(2)  # numba's pool up, as after a kernel
    blocker = threading.Event()
    threading.Thread(target=blocker.wait, daemon=False).start()
    marker = sys.argv[1]
    atexit.register(lambda: open(marker, "w").write("cleaned up"))
    sys.argv = ["carlaocc", *sys.argv[2:]]
    main()
""")


def _run(tmp_path, *args, timeout=120):
    marker = tmp_path / "atexit.txt"
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(marker), *args], capture_output=True, text=True,
                       timeout=timeout)
    return r, marker


def test_a_success_exits_0_with_threads_alive_and_cleanups_run(tmp_path):
    r, marker = _run(tmp_path, "stages")
    assert r.returncode == 0, r.stderr
    assert "voxelize:" in r.stdout  # flushed before leaving
    assert marker.read_text() == "cleaned up"  # the atexit handlers ran


def test_a_refusal_exits_2_with_threads_alive(tmp_path):
    r, marker = _run(tmp_path, "run", "--stages", "nope", "--root", str(tmp_path / "new"))
    assert r.returncode == 2 and r.stderr.startswith("error: --stages: unknown stage 'nope'"), r.stderr
    assert marker.exists() and not (tmp_path / "new").exists()


def test_a_usage_error_keeps_typers_exit_2(tmp_path):
    r, _ = _run(tmp_path, "--definitely-not-an-option")
    assert r.returncode == 2 and r.stderr.startswith("error: no such option --definitely-not-an-option"), r.stderr


def test_output_piped_into_a_closed_reader_ends_quietly():
    # `carlaocc stages | head -1`: the reader stops; the command ends 0 without an error line
    r = subprocess.run(f"{sys.executable} -m carlaocc stages | head -c 1", shell=True, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and len(r.stdout) == 1 and "error" not in r.stderr


@pytest.mark.slow
def test_repeated_ingest_runs_all_exit_0(tmp_path):
    # the corpus run that once ended 134 after a success, repeated: every run's code is 0
    src = tmp_path / "src"
    src.mkdir()
    (src / "pole.glb").write_bytes(shared_path("meshes/trimesh-models/simple_pole.glb").read_bytes())
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\n*.glb,Pole,utility_pole\n")
    codes = []
    for k in range(20):
        r = subprocess.run([sys.executable, "-m", "carlaocc", "ingest", "folder", str(src), "--category-map", str(cmap),
                            "--root", str(tmp_path / f"data{k % 2}")], capture_output=True, text=True, timeout=600)
        codes.append(r.returncode)
    assert codes == [0] * 20, codes
