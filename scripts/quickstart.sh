#!/usr/bin/env bash
# Installs what is missing, builds, generates a small cloud and renders it with
# nanovdbvolume to scenes/cloud.png (no user data needed).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
./build/bin/nvdb_make_test_grid noisy_cloud scenes/cloud.nvdb
"${PYTHON:-python3}" scenes/render_cloud.py scenes/cloud.nvdb scenes/cloud.png
