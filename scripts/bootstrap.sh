#!/usr/bin/env bash
# Install everything the project needs from its own files: uv (pinned) in .tools/, then the
# locked environment in .venv/ (uv.lock). Safe to run repeatedly.
set -euo pipefail
cd "$(dirname "$0")/.."
UV_VERSION="0.13.8"
PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
if [ ! -x .tools/bin/uv ] || [ "$(.tools/bin/uv --version | cut -d' ' -f2)" != "$UV_VERSION" ]; then
  "$PYTHON" -m venv .tools
  .tools/bin/pip install --quiet "uv==$UV_VERSION"
fi
.tools/bin/uv sync --frozen --all-extras --python "$PYTHON" --quiet
scripts/install_frontend.sh
