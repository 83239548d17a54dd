#!/usr/bin/env bash
# Set up softcbf-mj on a Debian machine: system libraries (as root), a virtual
# environment in .venv, and the package with pinned dependency versions.
# Idempotent: a second run only checks what is there.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
python_ok() { command -v python3 >/dev/null && python3 -c 'import sys, venv, ensurepip; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; }
python_ok || need_apt+=(python3 python3-venv)
# OSMesa: MuJoCo's CPU offscreen renderer (MUJOCO_GL=osmesa).
ldconfig -p 2>/dev/null | grep -q libOSMesa.so || need_apt+=(libosmesa6)
if [ ${#need_apt[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "setup: missing system packages: ${need_apt[*]}; run as root or: sudo apt-get install ${need_apt[*]}" >&2
    exit 1
  fi
  echo "setup: installing ${need_apt[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
# MuJoCo 4 splits its Python bindings into mujoco, mujoco-core, mujoco-studio and mujoco-studio-wasm,
# which all write into one mujoco/ directory; upgrading them in place can leave a mix of versions, so
# the old ones are uninstalled first. Only when an installed one differs from the pin: a second run
# keeps the installation.
mujoco_pin=$(sed -n 's/^mujoco==//p' constraints.txt)
mujoco_installed=$(.venv/bin/python - <<'PY'
from importlib import metadata
for name in ("mujoco", "mujoco-core", "mujoco-studio", "mujoco-studio-wasm"):
    try:
        print(name, metadata.version(name))
    except metadata.PackageNotFoundError:
        pass
PY
)
if [ -n "$mujoco_installed" ] && echo "$mujoco_installed" | grep -qv " $mujoco_pin\$"; then
  echo "setup: replacing $(echo "$mujoco_installed" | paste -sd, -) by MuJoCo $mujoco_pin (uninstalling first)"
  .venv/bin/python -m pip uninstall -q -y $(echo "$mujoco_installed" | cut -d' ' -f1)
fi
.venv/bin/python -m pip install -q -c constraints.txt -e '.[dev]'
echo "setup: ready ($(.venv/bin/python --version), $(.venv/bin/python -c 'import mujoco; print("mujoco", mujoco.__version__)'))"
