#!/usr/bin/env bash
# One-command set-up on a fresh Debian machine: system packages, a virtualenv in .venv,
# and the project installed (editable) with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."

# Open3D's wheel links libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
.venv/bin/python -m pip install -q -e ".[test,ray]"
.venv/bin/python -c "import open3d, cv2, pycolmap, scipy, numpy; print('stereo-recon set-up OK: open3d', open3d.__version__, 'opencv', cv2.__version__, 'pycolmap', pycolmap.__version__)"
