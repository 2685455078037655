#!/bin/sh
# service/static/favicon.ico (16, 32 and 48 px) from service/static/favicon.svg, rendered by
# headless Chromium (tests/browser/setup.sh installs it) and packed by Pillow (a matplotlib
# dependency). Run after changing the SVG; the ICO is committed.
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
STATIC="$HERE/../service/static"
TMP=$(mktemp -d)
printf '<html><body style="margin:0;background:transparent"><img src="file://%s" width="256" height="256"></body></html>' \
    "$STATIC/favicon.svg" > "$TMP/page.html"
chromium --headless=new --no-sandbox --disable-gpu --hide-scrollbars --default-background-color=00000000 \
    --window-size=256,256 --screenshot="$TMP/icon.png" "file://$TMP/page.html" >/dev/null 2>&1
"${PYTHON:-python3}" -c "
from PIL import Image
import sys
Image.open(sys.argv[1]).convert('RGBA').save(sys.argv[2], sizes=[(16, 16), (32, 32), (48, 48)])
" "$TMP/icon.png" "$STATIC/favicon.ico"
rm -rf "$TMP"
echo "wrote service/static/favicon.ico"
