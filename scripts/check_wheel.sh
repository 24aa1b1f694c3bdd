#!/usr/bin/env bash
# Build the wheel, install it into a scratch venv outside the checkout and fit a bundled sample
# with a preset: proves the installed distribution works without the source tree (package data,
# entry point, no stray top-level names). The scratch venv reuses .venv's third-party packages
# through a .pth line, so nothing large is installed twice; oprecon itself comes only from the
# wheel. Run by `make test`.
#
# The fit runs with numba's JIT off, on a coarse spacing (74 particles): every stage's code runs
# from the installed files in 15 s. With the JIT on it would compile every kernel for 3.5
# minutes, since numba's cache belongs to the source files' paths; `make test` compiles the same
# sources in the checkout.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
py=$root/.venv/bin/python
scratch=$(mktemp -d "${TMPDIR:-/tmp}/oprecon-wheel.XXXXXX")
trap 'rm -rf "$scratch"' EXIT

echo "check_wheel: building the wheel" >&2
"$py" -m pip wheel --quiet --no-deps --wheel-dir "$scratch/dist" . >"$scratch/build.log" 2>&1 ||
  { cat "$scratch/build.log" >&2; exit 1; }
wheel=$(ls "$scratch"/dist/oprecon-*.whl)

# Only `recon` (and the dist-info) may sit at the top of the wheel.
tops=$("$py" - "$wheel" <<'PY'
import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
print(" ".join(sorted({n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")})))
PY
)
if [ "$tops" != "recon" ]; then
  echo "check_wheel: the wheel installs top-level names other than 'recon': $tops" >&2
  exit 1
fi

"$py" -m venv --without-pip "$scratch/venv"
site=$("$scratch/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
deps=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
"$py" -m pip --python "$scratch/venv/bin/python" install --quiet --no-deps --no-index "$wheel" >&2
echo "$deps" >"$site/zz_oprecon_deps.pth"  # sorted after the wheel: its recon wins

cd "$scratch"  # nothing of the checkout is importable from here
"$scratch/venv/bin/python" - "$scratch" <<'PY'
import sys
import recon, recon.cli.main, recon.configs
for mod in (recon, recon.cli.main, recon.configs):
    assert mod.__file__.startswith(sys.argv[1]), f"{mod.__name__} imported from {mod.__file__}"
try:
    import cli  # noqa: F401
except ImportError:
    pass
else:
    raise SystemExit("check_wheel: a top-level 'cli' package is importable")
from importlib.resources import files
example = files("recon.configs") / "examples" / "batch_example.yaml"
assert example.is_file(), f"check_wheel: the batch example is not in the wheel ({example})"
PY
echo "check_wheel: fitting sample_data/square_hole-sparse.ply with --preset open_scan (installed wheel, JIT off)" >&2
NUMBA_DISABLE_JIT=1 "$scratch/venv/bin/oprecon" fit "$root/sample_data/square_hole-sparse.ply" \
  -o "$scratch/out.ply" --preset open_scan --spacing-relative 0.1 -q
# one test per line: set -e does not stop at the first command of an && list
test -s "$scratch/out.ply"
test -s "$scratch/out.report.json"
echo "check_wheel: ok ($(basename "$wheel"))" >&2
