#!/bin/sh
# Installs the system packages carlaocc's .venv needs on Debian/Ubuntu; `make` runs it before it
# creates .venv (the `syslibs` target), and .ci/run goes through `make test`, so a fresh machine
# needs nothing but the README's two commands.
#
#   sh tools/setup_system.sh [--test] [PYTHON]      (PYTHON: the interpreter make builds .venv with)
#
# --test (`make venv-test`, so `make test`; never `make dataset`): also a headless browser for the
#   browser tests (the docs site's pictures, `carlaocc view`): Debian's chromium, unless a
#   chromium, chromium-browser or google-chrome is already on PATH.
# - open3d's wheel links libusb-1.0 and (0.20) libEGL; opencv-python (imported by the D2NT normal
#   translator) links libGL, libgthread/libglib and libxcb: found with `ldconfig -p`.
# - `PYTHON -m venv` needs ensurepip, which a bare Debian python3 lacks (python3-venv).
# Nothing present is reinstalled and nothing is printed when all is present. What is missing is
# installed with apt-get when root, else with `sudo -n` (never a password prompt); only when
# neither works does it print one line naming the packages and the command, and exit 1.
set -eu

TEST=0
if [ "${1:-}" = "--test" ]; then
  TEST=1
  shift
fi
PYTHON=${1:-python3}

# package name of the venv module for this interpreter: python3 -> python3-venv,
# python3.12 -> python3.12-venv
case ${PYTHON##*/} in
  python3.[0-9]*) venv_pkg="${PYTHON##*/}-venv" ;;
  *) venv_pkg=python3-venv ;;
esac

missing=""

# ldconfig lives in /sbin, which is not on a Debian user's PATH
ldconfig_cmd=""
if command -v ldconfig >/dev/null 2>&1; then
  ldconfig_cmd=ldconfig
else
  for c in /sbin/ldconfig /usr/sbin/ldconfig; do
    if [ -x "$c" ]; then ldconfig_cmd=$c; break; fi
  done
fi
if [ -n "$ldconfig_cmd" ]; then
  cache=$("$ldconfig_cmd" -p 2>/dev/null || true)
  for pair in libusb-1.0.so.0:libusb-1.0-0 libEGL.so.1:libegl1 libGL.so.1:libgl1 \
              libgthread-2.0.so.0:libglib2.0-0 libxcb.so.1:libxcb1; do
    lib=${pair%%:*}
    case $cache in
      *"$lib "*) ;;
      *) missing="$missing ${pair##*:}" ;;
    esac
  done
fi

if ! "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1; then
  missing="$missing $venv_pkg"
fi

if [ "$TEST" = 1 ] && ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1 \
   && ! command -v google-chrome >/dev/null 2>&1; then
  missing="$missing chromium"
fi

[ -z "$missing" ] && exit 0
missing=${missing# }

if ! command -v apt-get >/dev/null 2>&1; then
  echo "error: carlaocc needs the system packages (Debian names) $missing; install them with your system's package manager" >&2
  exit 1
fi

export DEBIAN_FRONTEND=noninteractive
if [ "$(id -u)" = 0 ]; then
  set -- apt-get
elif command -v sudo >/dev/null 2>&1 && sudo -n true >/dev/null 2>&1; then
  # sudo resets the environment: pass the variable on its command line
  set -- sudo -n DEBIAN_FRONTEND=noninteractive apt-get
else
  echo "error: carlaocc needs the system packages $missing; install them with: sudo apt-get update && sudo apt-get install -y $missing" >&2
  exit 1
fi

echo "installing the system packages carlaocc needs: $missing ($* install)"
"$@" update -qq
# shellcheck disable=SC2086  # $missing is a list of package names
"$@" install -y -qq --no-install-recommends $missing >/dev/null
