#!/bin/sh
# Installs what the PostgreSQL tests need on a clean Debian/Ubuntu machine: the PostgreSQL server
# binaries (initdb, pg_ctl, postgres). The Python driver, psycopg, is a runtime dependency and
# comes with `pip install -e '.[test]'`. The tests make a throwaway cluster of their own: the
# packaged cluster and service are not used (and not started here).
# Idempotent: does nothing when the binaries are already there. Needs root (or sudo) for apt-get.
# Prints the directory of the binaries on success.
set -eu
find_bin() {
    if [ -n "${PG_BINDIR:-}" ] && [ -x "$PG_BINDIR/initdb" ]; then echo "$PG_BINDIR"; return 0; fi
    for d in $(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V -r); do
        if [ -x "$d/initdb" ] && [ -x "$d/pg_ctl" ] && [ -x "$d/postgres" ]; then echo "$d"; return 0; fi
    done
    return 1
}
if find_bin; then
    exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo -n"; else echo "setup.sh: need root to apt-get install postgresql" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
# apt-get holds dpkg's lock: processes of the suite (pytest-xdist) take turns on this lock instead of failing
APT_LOCK=""
if command -v flock >/dev/null 2>&1; then APT_LOCK="flock -w 1800 ${TMPDIR:-/tmp}/spacearm-apt.lock"; fi
# the Debian package also creates the `postgres` OS user the tests run the server as
$APT_LOCK sh -c "$SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends postgresql >/dev/null"
find_bin
