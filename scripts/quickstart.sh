#!/usr/bin/env bash
# Installs what is missing, builds and installs the package (pip install .),
# generates a small cloud (a .vdb, with vdb2nvdb) and renders it with the
# installed nanovdb-render to scenes/cloud.png (no user data needed).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh --no-tests
vdb2nvdb generate cloud scenes/cloud.vdb scenes/cloud.nvdb
nanovdb-render scenes/cloud.vdb -o scenes/cloud.png
