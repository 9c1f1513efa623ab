#!/usr/bin/env bash
# Install the dashboard's JavaScript libraries (frontend/package-lock.json, exact pins) into
# frontend/node_modules with `npm ci`, when node_modules is missing or was installed from a
# different lock file. Nothing is built: the app serves the libraries' dist files as they are.
# Safe to run repeatedly (a no-op when up to date).
set -euo pipefail
cd "$(dirname "$0")/../frontend"
if ! command -v npm >/dev/null 2>&1; then
  echo "install_frontend: npm is missing; install Node.js >= 18 (Debian: apt-get install -y npm)" >&2
  exit 1
fi
STAMP=node_modules/.activetouch-lock.sha256
WANT="$(sha256sum package-lock.json | cut -d' ' -f1)"
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$WANT" ] \
  && [ -f node_modules/chart.js/dist/chart.umd.min.js ]; then
  exit 0
fi
echo "install_frontend: npm ci (frontend/package-lock.json)" >&2
npm ci --no-audit --no-fund --loglevel=error
echo "$WANT" >"$STAMP"
