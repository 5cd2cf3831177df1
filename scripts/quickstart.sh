#!/usr/bin/env bash
# Installs what is missing, builds, generates a small cloud (as .vdb, converted
# to .nvdb by vdb2nvdb) and renders it with nanovdbvolume to scenes/cloud.png
# (no user data needed).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
./build/bin/vdb2nvdb generate cloud scenes/cloud.vdb scenes/cloud.nvdb
"${PYTHON:-python3}" scenes/render_cloud.py scenes/cloud.nvdb scenes/cloud.png
