#!/usr/bin/env bash
# Install headless Chromium from Debian for the browser tests (tests/e2e, marker "browser"),
# unless /usr/bin/chromium is already there. Playwright drives it through `executable_path`;
# `playwright install` (a download outside the package registries) is never used.
# Safe to run repeatedly; needs root (or sudo) only when Chromium is missing.
set -euo pipefail
CHROMIUM="${ACTIVETOUCH_CHROMIUM:-/usr/bin/chromium}"
if [ -x "$CHROMIUM" ]; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
  else
    echo "install_browser: $CHROMIUM is missing and this user cannot install it" \
      "(run 'apt-get install -y chromium' as root)" >&2
    exit 1
  fi
fi
echo "install_browser: installing Debian's chromium (headless browser tests)" >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >/dev/null
"$CHROMIUM" --version >&2
