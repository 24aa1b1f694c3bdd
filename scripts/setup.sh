#!/usr/bin/env bash
# Set up oprecon in ./.venv: system library for Open3D, virtualenv, package + dev tools.
# Idempotent; `make demo` and `make test` call it.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}

have_libusb() {
  if command -v ldconfig >/dev/null 2>&1 && ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    return 0
  fi
  for d in /usr/lib /usr/lib64 /lib /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/local/lib; do
    [ -e "$d/libusb-1.0.so.0" ] && return 0
  done
  return 1
}

if ! have_libusb; then
  if [ "$(uname -s)" = "Linux" ]; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
      echo "setup: installing libusb-1.0-0 (needed by Open3D)" >&2
      apt-get update -qq >&2
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >&2
    else
      echo "setup: Open3D needs the system library libusb-1.0, which is missing." >&2
      echo "setup: install it, then re-run:  sudo apt-get install -y libusb-1.0-0" >&2
      echo "setup: (Fedora: sudo dnf install libusb1; Arch: sudo pacman -S libusb)" >&2
      exit 2
    fi
  fi
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PYTHON --version 2>&1)" >&2
  "$PYTHON" -m venv .venv
fi

stamp=.venv/.oprecon-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing oprecon and its dependencies into .venv" >&2
  .venv/bin/python -m pip install --quiet --upgrade pip >&2 || true
  .venv/bin/python -m pip install --quiet -e ".[dev]" >&2
  touch "$stamp"
fi
# byte code of the package, as a non-editable install writes it: an editable install leaves it
# to the first import, which writes none when PYTHONDONTWRITEBYTECODE is set (then every
# process compiles ~70 modules from source, ~0.1 s of each start-up)
.venv/bin/python -m compileall -q recon cli >/dev/null
