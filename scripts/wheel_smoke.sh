#!/usr/bin/env bash
# The wheel as a user gets it: build the sdist and, from it, the wheel; install the wheel into a clean virtual
# environment in a temporary folder with the NEWEST dependency versions pyproject.toml allows (no constraints.txt);
# then check that its top-level packages come from it alone and, from a folder outside the checkout, run `softcbf
# list`, a short run, a shipped study by name, `softcbf examples`, a shipped study from the copied examples and a
# short emulated hardware run. Any error stops it
# (exit status != 0, the failing line named). CI runs it after the test suite (.ci/run); docs/install.md.
#
#   bash scripts/wheel_smoke.sh            # WHEEL_SMOKE_KEEP=1 keeps the temporary folder and says where
#
# Needs python3 (>= 3.11) with venv, OSMesa (scripts/setup.sh installs both) and the package index. The build uses
# .venv's `build` and setuptools (--no-isolation) where scripts/setup.sh made .venv, else an isolated build.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
start=$SECONDS
step() { echo "wheel smoke [$((SECONDS - start)) s]: $*"; }
trap 'echo "wheel smoke FAILED (line $LINENO, exit $?): $BASH_COMMAND" >&2' ERR

tmp=$(mktemp -d -t softcbf-wheel-smoke.XXXXXX)
if [ "${WHEEL_SMOKE_KEEP:-}" = 1 ]; then
  trap 'echo "wheel smoke: kept $tmp"' EXIT
else
  trap 'rm -rf "$tmp"' EXIT
fi
unset PYTHONPATH PIP_CONSTRAINT PIP_REQUIRE_VIRTUALENV  # nothing of the checkout or of a pinned set leaks in

step "building the sdist and, from it, the wheel"
if [ -x .venv/bin/python ] && .venv/bin/python -c 'import build, setuptools' 2>/dev/null; then
  .venv/bin/python -m build --no-isolation --outdir "$tmp/dist" . >"$tmp/build.log" 2>&1 || { tail -40 "$tmp/build.log" >&2; false; }
else
  python3 -m venv "$tmp/build-env"
  "$tmp/build-env/bin/python" -m pip install -q --upgrade pip build
  "$tmp/build-env/bin/python" -m build --outdir "$tmp/dist" . >"$tmp/build.log" 2>&1 || { tail -40 "$tmp/build.log" >&2; false; }
fi
wheel=$(ls "$tmp"/dist/*.whl)
step "built $(basename "$wheel")"

step "installing it into a clean venv with the newest allowed dependencies"
python3 -m venv "$tmp/venv"
py=$tmp/venv/bin/python
"$py" -m pip install -q --upgrade pip
"$py" -m pip install -q --upgrade --upgrade-strategy eager "$wheel"
"$py" - "$repo/constraints.txt" <<'PY'
import sys
from importlib.metadata import version
pinned = dict(line.strip().split("==", 1) for line in open(sys.argv[1]) if "==" in line)
for name in ("mujoco", "opencv-python-headless", "optuna", "numpy", "numba", "pandas", "dask", "gymnasium"):
    v = version(name)
    pin = pinned.get(name)
    print(f"wheel smoke: resolved {name} {v}" + ("" if pin is None else " (constraints.txt pins the same)" if pin == v
                                                 else f" (constraints.txt pins {pin})"))
print(f"wheel smoke: python {sys.version.split()[0]}")
PY
bin=$tmp/venv/bin

work=$tmp/elsewhere  # outside the checkout: only the installed wheel is importable
mkdir "$work"
cd "$work"
where=$("$py" -c 'import softcbf, scenarios; print(softcbf.__file__)')
case "$where" in "$tmp/venv/"*) ;; *) echo "wheel smoke: softcbf imported from $where, not the clean venv" >&2; exit 1 ;; esac
# The wheel's top-level packages have generic names (docs/install.md, "The top-level package names"): each must come
# from softcbf-mj alone.
"$py" - <<'PY'
from importlib.metadata import distribution, packages_distributions
ours = sorted({f.parts[0] for f in distribution("softcbf-mj").files
               if len(f.parts) > 1 and not f.parts[0].startswith(".") and not f.parts[0].endswith(".dist-info")})
owners = packages_distributions()
shared = {name: owners.get(name) for name in ours if owners.get(name) != ["softcbf-mj"]}
if shared:
    raise SystemExit(f"wheel smoke: top-level packages shared with other distributions: {shared}")
print(f"wheel smoke: top-level packages {', '.join(ours)}: each from softcbf-mj alone")
PY

step "softcbf --version, softcbf list"
"$bin/softcbf" --version
"$bin/softcbf" list >list.txt
grep -q paper_sim list.txt

step "softcbf run paper_sim (0.3 s)"
"$bin/softcbf" run paper_sim --duration 0.3 --progress false --out runs/paper_sim
test -s runs/paper_sim/summary.json

step "softcbf study run mismatch_box_contact (a shipped study by name; 2 samples of 0.3 s)"
"$bin/softcbf" study run mismatch_box_contact --out runs/box --samples 2 --set fixed.duration=0.3 --workers 1 --no-progress
test -s runs/box/results.parquet && test -s runs/box/report.md

step "softcbf examples mine (and its refusal to overwrite)"
"$bin/softcbf" examples mine
test -s mine/examples/clip_filter.py && test -s mine/studies/mismatch_box_contact.toml
refused=0  # an expected refusal: in a `||` list the ERR trap (and errexit) leave it alone
"$bin/softcbf" examples mine 2>refused.txt || refused=$?
if [ "$refused" -ne 2 ] || [ "$(wc -l <refused.txt)" -ne 1 ]; then
  echo "wheel smoke: softcbf examples into a full folder gave exit $refused, not 2 with one line:" >&2
  cat refused.txt >&2
  exit 1
fi

step "from the copy: softcbf study run examples/clip_filter_study.toml (a FILE.py filter; 1 sample of 0.3 s)"
(cd mine && "$bin/softcbf" study run examples/clip_filter_study.toml --out ../runs/clip --samples 1 \
   --set fixed.duration=0.3 --workers 1 --no-progress)
test -s runs/clip/results.parquet

step "softcbf hardware hardware_emulated (a shipped configuration by name; 1 s, emulated board, virtual camera)"
"$bin/softcbf" hardware hardware_emulated --duration 1 --out runs/hardware
test -s runs/hardware/summary.json

step "passed"
