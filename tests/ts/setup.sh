#!/bin/sh
# Installs what the TypeScript client test needs: Node.js and npm (apt-get, when missing), then
# the pinned packages of package-lock.json (`npm ci`) into tests/ts/node_modules. Idempotent and
# quick when nothing changed: node_modules is kept between runs and reinstalled only when the
# lockfile changes (its hash is stamped into node_modules). Needs root (or sudo) for apt-get.
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
sh "$HERE/../../web/node.sh"  # node and npm via apt-get when missing
STAMP="$HERE/node_modules/.spacearm-lock"
WANT=$(sha256sum "$HERE/package-lock.json" | cut -d' ' -f1)
if [ "$(cat "$STAMP" 2>/dev/null || true)" != "$WANT" ]; then
    (cd "$HERE" && npm ci --prefer-offline --no-audit --no-fund --loglevel=error)
    echo "$WANT" > "$STAMP"
fi
