#!/usr/bin/env bash
# Create .venv and install tofmetry with everything it needs, including the system
# library Open3D needs to import (libusb-1.0.so.0). Idempotent; fast when already set up.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

need_sys=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || need_sys+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep -q 'libgomp.so.1' || need_sys+=(libgomp1)
if [ "${TOFMETRY_BROWSER_TESTS:-1}" = "1" ] && ! command -v chromium >/dev/null 2>&1; then
  need_sys+=(chromium)
fi
if [ ${#need_sys[@]} -gt 0 ]; then
  echo "[setup] installing system packages: ${need_sys[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  if command -v apt-get >/dev/null 2>&1; then
    $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_sys[@]}" >/dev/null \
      || echo "[setup] WARNING: could not install ${need_sys[*]}; please install them with your package manager"
  else
    echo "[setup] please install: ${need_sys[*]} (libusb-1.0 is required by Open3D)"
  fi
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv"
  "$PY" -m venv .venv
fi
stamp=".venv/.tofmetry-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[setup] installing tofmetry and its dependencies into .venv"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test,mkv,e57,batch,realsense]"
  touch "$stamp"
fi
