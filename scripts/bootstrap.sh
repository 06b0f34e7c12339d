#!/usr/bin/env bash
# Installs everything the project needs on a fresh Debian machine with Python 3.11 or 3.12:
# the one system library open3d links against, a virtual environment in .venv,
# and the dpsi package with its test extras. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = 0 ]; then
        apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "bootstrap: open3d needs libusb-1.0-0; run: sudo apt-get install libusb-1.0-0" >&2
        exit 1
    fi
fi

PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null || PYTHON=python3
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
