#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: the doctest suites
# (through ctest), a short libFuzzer run over the loader, the benchmark
# harness in its fast mode, and the pytest suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
echo "== doctest (ctest)"
ctest --test-dir build --output-on-failure --parallel "$(nproc)"
echo "== fuzz (short run; NVDB_FUZZ_SECONDS=${NVDB_FUZZ_SECONDS:-20})"
# tests/fuzz/fuzz_nvdb.cpp with clang (libFuzzer + ASan + UBSan), in its own
# build directory. Seeds: small generated grids + ../shared/data (in place).
CC=clang-14 CXX=clang++-14 cmake -S . -B build-fuzz -G Ninja -DNVDB_BUILD_FUZZ=ON \
  -DNVDB_BUILD_TOOLS=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DPython_EXECUTABLE="$(command -v "${PYTHON:-python3}")" >/dev/null
cmake --build build-fuzz --target fuzz_nvdb
mkdir -p build-fuzz/seeds build-fuzz/corpus
for g in single_voxel lower_tiles upper_tiles empty constant_cube nonzero_background \
         far_coords root_tiles_negative fog_sphere; do
  [ -f "build-fuzz/seeds/${g}_zip.nvdb" ] ||
    build/bin/nvdb_make_test_grid "$g" "build-fuzz/seeds/${g}_zip.nvdb" --codec zip >/dev/null
done
[ -f build-fuzz/seeds/lower_tiles_blosc.nvdb ] ||
  build/bin/nvdb_make_test_grid lower_tiles build-fuzz/seeds/lower_tiles_blosc.nvdb --codec blosc >/dev/null
# Every value type: quantized, half (a raw grid buffer) and Vec3f leaves
for t in fp4 fp8 fp16 fpn half vec3f; do
  [ -f "build-fuzz/seeds/lower_tiles_${t}.nvdb" ] ||
    build/bin/nvdb_make_test_grid lower_tiles "build-fuzz/seeds/lower_tiles_${t}.nvdb" --type "$t" >/dev/null
done
[ -f build-fuzz/seeds/single_voxel_none.nvdb ] ||
  build/bin/nvdb_make_test_grid single_voxel build-fuzz/seeds/single_voxel_none.nvdb >/dev/null
# A root tile key that no coordinate has (bit 20 set): validation refuses it;
# accepted, the root index would serve the tile and PNanoVDB never find it
[ -f build-fuzz/seeds/single_voxel_key_bit20.nvdb ] ||
  build/bin/nvdb_make_test_grid single_voxel build-fuzz/seeds/single_voxel_key_bit20.nvdb \
    --root-key-bit 20 >/dev/null
shared="${NVDB_SHARED_DATA:-../shared/data}"
build-fuzz/bin/fuzz_nvdb -max_total_time="${NVDB_FUZZ_SECONDS:-20}" -print_final_stats=1 \
  build-fuzz/corpus build-fuzz/seeds $( [ -d "$shared" ] && echo "$shared" ) 2>&1 | tail -n 8
echo "== bench (fast mode: the harness runs end to end; timings are not asserted)"
"${PYTHON:-python3}" bench/run.py --fast
# pytest last: its summary line closes the run
echo "== pytest"
"${PYTHON:-python3}" -m pytest -q tests -p no:cacheprovider "$@"
