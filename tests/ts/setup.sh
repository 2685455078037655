#!/bin/sh
# Installs what the TypeScript client test needs: Node.js and npm (apt-get, when missing), then
# the pinned packages of package-lock.json (`npm ci`) into tests/ts/node_modules. Idempotent and
# quick when nothing changed: node_modules is kept between runs and reinstalled only when the
# lockfile changes (its hash is stamped into node_modules). Needs root (or sudo) for apt-get.
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    SUDO=""
    if [ "$(id -u)" != "0" ]; then
        if command -v sudo >/dev/null 2>&1; then SUDO="sudo -n"; else echo "setup.sh: need root to apt-get install nodejs npm" >&2; exit 1; fi
    fi
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
command -v node >/dev/null && command -v npm >/dev/null
STAMP="$HERE/node_modules/.spacearm-lock"
WANT=$(sha256sum "$HERE/package-lock.json" | cut -d' ' -f1)
if [ "$(cat "$STAMP" 2>/dev/null || true)" != "$WANT" ]; then
    (cd "$HERE" && npm ci --prefer-offline --no-audit --no-fund --loglevel=error)
    echo "$WANT" > "$STAMP"
fi
