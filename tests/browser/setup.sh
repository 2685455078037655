#!/bin/sh
# Installs what the browser tests need on a clean Debian/Ubuntu machine: Chromium and its
# WebDriver (the Python side, selenium, comes with `pip install -e '.[test]'`).
# Idempotent: does nothing when both are already on PATH. Needs root (or sudo) for apt-get.
set -eu
if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
    exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo -n"; else echo "setup.sh: need root to apt-get install chromium" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
# apt-get holds dpkg's lock: processes of the suite (pytest-xdist) take turns on this lock instead of failing
APT_LOCK=""
if command -v flock >/dev/null 2>&1; then APT_LOCK="flock -w 1800 ${TMPDIR:-/tmp}/spacearm-apt.lock"; fi
# Debian names them chromium + chromium-driver; Ubuntu's chromium-browser is a snap stub, so Debian first
$APT_LOCK sh -c "$SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends chromium chromium-driver fonts-dejavu-core >/dev/null"
command -v chromium >/dev/null && command -v chromedriver >/dev/null
