#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: the doctest suites
# (through ctest) and the pytest suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
echo "== doctest (ctest)"
ctest --test-dir build --output-on-failure
echo "== pytest"
"${PYTHON:-python3}" -m pytest -q tests -p no:cacheprovider "$@"
