#!/bin/sh
# Builds the 3D view's three.js bundle from the pinned packages of web/package-lock.json:
# `npm ci` (into web/node_modules, only when the lockfile changed), then esbuild bundles what
# web/three-entry.js exports (tree-shaken, minified, license comments kept at the end) into
# service/static/three-<version>.min.js, and copies three's LICENSE beside it.
#
#   sh web/build.sh          rebuild the committed files (`make vendor`)
#   sh web/build.sh --check  rebuild into a temporary directory and fail unless the committed
#                            files are byte for byte what the lockfile builds (the test suite)
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
STATIC="$HERE/../service/static"
sh "$HERE/node.sh"
STAMP="$HERE/node_modules/.spacearm-lock"
WANT=$(sha256sum "$HERE/package-lock.json" | cut -d' ' -f1)
if [ "$(cat "$STAMP" 2>/dev/null || true)" != "$WANT" ]; then
    (cd "$HERE" && npm ci --prefer-offline --no-audit --no-fund --loglevel=error)
    echo "$WANT" > "$STAMP"
fi
VERSION=$(node -p "require('$HERE/node_modules/three/package.json').version")
OUT="$STATIC"
if [ "${1:-}" = "--check" ]; then OUT=$(mktemp -d); fi
(cd "$HERE" && node_modules/.bin/esbuild three-entry.js --bundle --format=esm --minify --legal-comments=eof \
    --target=es2020 --log-level=warning --outfile="$OUT/three-$VERSION.min.js")
cp "$HERE/node_modules/three/LICENSE" "$OUT/three-LICENSE.txt"
if [ "${1:-}" = "--check" ]; then
    status=0
    for name in "three-$VERSION.min.js" three-LICENSE.txt; do
        if ! cmp -s "$OUT/$name" "$STATIC/$name"; then
            echo "build.sh: service/static/$name is not what web/package-lock.json builds (run: sh web/build.sh)" >&2
            status=1
        fi
    done
    rm -rf "$OUT"
    exit $status
fi
echo "built service/static/three-$VERSION.min.js ($(wc -c < "$STATIC/three-$VERSION.min.js") bytes)"
