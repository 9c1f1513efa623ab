#!/usr/bin/env bash
# The whole test command: set-up, then ruff, mypy, import-linter contracts and pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
scripts/install_browser.sh
export PATH="$PWD/.venv/bin:$PATH"
# One BLAS thread per process: the problems are small and the machines have 2 shared cores.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
echo "== ruff"; ruff check .; ruff format --check .
echo "== mypy"; mypy core hardware app bench
echo "== import-linter"; lint-imports
echo "== pytest"
if [ $# -eq 0 ]; then
  # Two xdist workers (one per core); tests sharing the demo or the Dask cluster stay together.
  # Schemathesis generates its API tests at run time, and under xdist only the first of them
  # runs: they run on their own, after.
  pytest -n 2 --dist loadgroup --ignore=tests/app/test_openapi.py
  pytest tests/app/test_openapi.py
else
  pytest "$@"
fi
