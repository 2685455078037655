#!/bin/sh
# Node.js and npm, installed with apt-get when missing (needs root or sudo); shared by
# web/build.sh and tests/ts/setup.sh. Idempotent.
set -eu
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    SUDO=""
    if [ "$(id -u)" != "0" ]; then
        if command -v sudo >/dev/null 2>&1; then SUDO="sudo -n"; else echo "node.sh: need root to apt-get install nodejs npm" >&2; exit 1; fi
    fi
    export DEBIAN_FRONTEND=noninteractive
    # apt-get holds dpkg's lock: processes of the suite (pytest-xdist) take turns on this lock instead of failing
    APT_LOCK=""
    if command -v flock >/dev/null 2>&1; then APT_LOCK="flock -w 1800 ${TMPDIR:-/tmp}/spacearm-apt.lock"; fi
    $APT_LOCK sh -c "$SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null"
fi
command -v node >/dev/null && command -v npm >/dev/null
