"""tools/setup_system.sh, the set-up the Makefile's `syslibs` target (and so `make dataset`,
`make test` and .ci/run) runs before it creates .venv: run with stand-in `ldconfig`, `id`,
`apt-get`, `sudo` and python executables alone on PATH, which record their calls. Nothing is
installed."""

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "setup_system.sh"
SH = shutil.which("sh") or "/bin/sh"

# soname -> Debian package, as the script checks them
LIBS = {
    "libusb-1.0.so.0": "libusb-1.0-0",
    "libEGL.so.1": "libegl1",
    "libGL.so.1": "libgl1",
    "libgthread-2.0.so.0": "libglib2.0-0",
    "libxcb.so.1": "libxcb1",
}
INSTALL = "install -y -qq --no-install-recommends"


def _write(path: Path, text: str) -> None:
    path.write_text("#!/bin/sh\n" + text)
    path.chmod(0o755)


def run_setup(
    tmp: Path,
    *,
    libs=tuple(LIBS),
    uid: int = 0,
    sudo: str | None = None,  # None: no sudo on PATH; "ok": sudo -n works; "password": it refuses
    venv: bool = True,
    apt: str | None = "ok",  # None: no apt-get on PATH; "fail": apt-get exits 100
    python: str = "python3",
    test: bool = False,  # --test: the tests' packages too (a headless Chromium)
    browser: str | None = None,  # the name of a browser executable on PATH, if any
):
    """Runs the script with only the stand-ins on PATH; returns (result, recorded calls)."""
    bin_ = tmp / "bin"
    bin_.mkdir()
    calls = tmp / "calls"
    calls.touch()
    log = f'>> "{calls}"'
    lines = "".join(
        f"printf '\\t%s (libc6,x86-64) => /lib/x86_64-linux-gnu/%s\\n' {lib} {lib}\n" for lib in libs
    )
    _write(bin_ / "ldconfig", f"printf '%s libs found in cache\\n' {len(libs)}\n{lines}")
    _write(bin_ / "id", f'[ "$1" = -u ] && echo {uid} && exit 0\necho "uid={uid}"\n')
    if apt is not None:
        _write(
            bin_ / "apt-get",
            f'echo "apt-get [DEBIAN_FRONTEND=${{DEBIAN_FRONTEND:-}}] $*" {log}\n'
            + ("exit 100\n" if apt == "fail" else "exit 0\n"),
        )
    if sudo is not None:
        _write(
            bin_ / "sudo",
            f'echo "sudo $*" {log}\n'
            + ('echo "sudo: a password is required" >&2\nexit 1\n' if sudo != "ok" else "")
            + '[ "$1" = -n ] || { echo "sudo: would prompt" >&2; exit 1; }\nshift\n'
            # like sudo's env_reset: only VAR=value arguments reach the command
            + 'unset DEBIAN_FRONTEND\n'
            + 'while [ $# -gt 0 ]; do case $1 in *=*) export "$1"; shift ;; *) break ;; esac; done\n'
            + 'exec "$@"\n',
        )
        _write(bin_ / "true", "exit 0\n")  # what `sudo -n true` runs
    py = bin_ / python
    _write(py, f'echo "{python} $*" {log}\nexit {0 if venv else 1}\n')
    if browser is not None:
        _write(bin_ / browser, "exit 0\n")
    env = {"PATH": str(bin_), "HOME": str(tmp)}  # no DEBIAN_FRONTEND: the script must set it
    result = subprocess.run(
        [SH, str(SCRIPT), *(["--test"] if test else []), str(py)], env=env, capture_output=True, text=True,
        timeout=60
    )
    recorded = [ln for ln in calls.read_text().splitlines() if not ln.startswith(python)]
    return result, recorded


def test_all_present_installs_nothing_and_is_quiet(tmp_path):
    result, calls = run_setup(tmp_path, uid=1000, sudo="ok")
    assert result.returncode == 0, result.stderr
    assert calls == []
    assert result.stdout == "" and result.stderr == ""


def test_all_present_checks_the_interpreter_make_uses(tmp_path):
    result, _ = run_setup(tmp_path)
    assert result.returncode == 0
    assert (tmp_path / "calls").read_text().splitlines() == ["python3 -c import ensurepip, venv"]


def test_missing_libs_as_root_apt_get_installs_exactly_them(tmp_path):
    result, calls = run_setup(tmp_path, libs=("libGL.so.1", "libxcb.so.1"), uid=0, sudo="ok")
    assert result.returncode == 0, result.stderr
    assert calls == [
        "apt-get [DEBIAN_FRONTEND=noninteractive] update -qq",
        f"apt-get [DEBIAN_FRONTEND=noninteractive] {INSTALL} libusb-1.0-0 libegl1 libglib2.0-0",
    ]
    assert "libusb-1.0-0 libegl1 libglib2.0-0" in result.stdout


def test_missing_as_non_root_with_sudo_uses_sudo_n(tmp_path):
    result, calls = run_setup(tmp_path, libs=(), uid=1000, sudo="ok", venv=False)
    assert result.returncode == 0, result.stderr
    pkgs = "libusb-1.0-0 libegl1 libgl1 libglib2.0-0 libxcb1 python3-venv"
    assert calls == [
        "sudo -n true",
        "sudo -n DEBIAN_FRONTEND=noninteractive apt-get update -qq",
        "apt-get [DEBIAN_FRONTEND=noninteractive] update -qq",
        f"sudo -n DEBIAN_FRONTEND=noninteractive apt-get {INSTALL} {pkgs}",
        f"apt-get [DEBIAN_FRONTEND=noninteractive] {INSTALL} {pkgs}",
    ]


def _assert_one_line_naming(result, calls, *pkgs):
    assert result.returncode != 0
    assert not any(c.startswith("apt-get") for c in calls), calls
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for pkg in pkgs:
        assert pkg in lines[0]
    assert "apt-get install" in lines[0]


def test_missing_with_sudo_needing_a_password_prints_one_line(tmp_path):
    result, calls = run_setup(tmp_path, libs=("libGL.so.1",), uid=1000, sudo="password")
    assert calls == ["sudo -n true"]  # asked non-interactively, never prompted
    _assert_one_line_naming(result, calls, "libusb-1.0-0 libegl1 libglib2.0-0 libxcb1")


def test_missing_with_no_sudo_prints_one_line(tmp_path):
    result, calls = run_setup(tmp_path, libs=tuple(LIBS), uid=1000, sudo=None, venv=False)
    assert calls == []
    _assert_one_line_naming(result, calls, "python3-venv")
    assert "libusb" not in result.stderr


def test_python3_venv_missing_is_installed(tmp_path):
    result, calls = run_setup(tmp_path, uid=0, venv=False)
    assert result.returncode == 0, result.stderr
    assert calls[-1] == f"apt-get [DEBIAN_FRONTEND=noninteractive] {INSTALL} python3-venv"
    assert len(calls) == 2


def test_a_versioned_interpreter_gets_its_own_venv_package(tmp_path):
    result, calls = run_setup(tmp_path, uid=0, venv=False, python="python3.12")
    assert result.returncode == 0, result.stderr
    assert calls[-1].endswith(f"{INSTALL} python3.12-venv")


def test_no_apt_get_names_the_packages_and_fails(tmp_path):
    result, calls = run_setup(tmp_path, libs=(), uid=0, apt=None)
    assert result.returncode != 0 and calls == []
    assert len(result.stderr.strip().splitlines()) == 1
    assert "libusb-1.0-0 libegl1 libgl1 libglib2.0-0 libxcb1" in result.stderr


def test_a_failing_apt_get_fails_the_set_up(tmp_path):
    result, calls = run_setup(tmp_path, libs=(), uid=0, apt="fail")
    assert result.returncode != 0
    assert calls == ["apt-get [DEBIAN_FRONTEND=noninteractive] update -qq"]


@settings(max_examples=25, deadline=None)
@given(
    present=st.sets(st.sampled_from(sorted(LIBS))),
    venv=st.booleans(),
    uid=st.sampled_from([0, 1000]),
)
def test_installs_exactly_what_is_missing(present, venv, uid):
    with tempfile.TemporaryDirectory() as tmp:
        result, calls = run_setup(Path(tmp), libs=tuple(present), uid=uid, sudo="ok", venv=venv)
    expected = [pkg for lib, pkg in LIBS.items() if lib not in present] + ([] if venv else ["python3-venv"])
    assert result.returncode == 0, result.stderr
    installs = [c for c in calls if c.startswith("apt-get") and " install " in c]
    if not expected:
        assert calls == [] and result.stdout == ""
    else:
        assert installs == [f"apt-get [DEBIAN_FRONTEND=noninteractive] {INSTALL} {' '.join(expected)}"]
        assert sum(" update " in c or c.endswith(" update -qq") for c in calls if c.startswith("apt-get")) == 1


def test_the_test_variant_installs_chromium_only_when_no_browser_is_there(tmp_path):
    (tmp_path / "none").mkdir()
    result, calls = run_setup(tmp_path / "none", test=True)
    assert result.returncode == 0, result.stderr
    assert calls == ["apt-get [DEBIAN_FRONTEND=noninteractive] update -qq",
                     f"apt-get [DEBIAN_FRONTEND=noninteractive] {INSTALL} chromium"]
    for name in ("chromium", "chromium-browser", "google-chrome"):
        (tmp_path / name).mkdir()
        result, calls = run_setup(tmp_path / name, test=True, browser=name)
        assert result.returncode == 0 and calls == [], (name, calls)
    # without --test (make dataset) no browser is ever installed
    (tmp_path / "plain").mkdir()
    result, calls = run_setup(tmp_path / "plain")
    assert result.returncode == 0 and calls == []


def test_make_test_installs_the_browser_and_make_dataset_does_not():
    make = (ROOT / "Makefile").read_text()
    recipe = make.split("\nsyslibs-test:", 1)[1].split("\n\n", 1)[0]
    assert "tools/setup_system.sh --test" in recipe
    venv_test = next(ln for ln in make.splitlines() if ln.startswith("venv-test:"))
    assert "syslibs-test" in venv_test
    dataset = next(ln for ln in make.splitlines() if ln.startswith("dataset:"))
    assert "test" not in dataset and "--test" not in make.split("\nsyslibs:", 1)[1].split("\n\n", 1)[0]


def test_make_and_ci_go_through_the_script():
    make = (ROOT / "Makefile").read_text()
    recipe = make.split("\nsyslibs:", 1)[1].split("\n\n", 1)[0]
    assert "tools/setup_system.sh" in recipe
    installed = next(ln for ln in make.splitlines() if ln.startswith("$(BIN)/.installed:"))
    assert "syslibs" in installed  # runs before `python3 -m venv`
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci and "apt-get" not in ci and "ldconfig" not in ci
    assert os.access(ROOT / ".ci" / "run", os.X_OK)
