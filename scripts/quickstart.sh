#!/usr/bin/env bash
# Installs what is missing, builds and installs the package (pip install .,
# its plugins for llvm_ad_rgb), generates a small cloud (a .vdb, with
# vdb2nvdb) and renders it with the installed nanovdb-render to
# scenes/cloud.png (no user data needed).
set -euo pipefail
cd "$(dirname "$0")/.."
# Only the variant nanovdb-render uses (its default): a first build in
# minutes; pip install . and the test command build all 13
bash scripts/install.sh --no-tests --variants=llvm_ad_rgb
vdb2nvdb generate cloud scenes/cloud.vdb scenes/cloud.nvdb
nanovdb-render scenes/cloud.vdb -o scenes/cloud.png
