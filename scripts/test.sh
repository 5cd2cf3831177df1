#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: the doctest suites
# (through ctest), a short libFuzzer run over the loader, the benchmark
# harness in its fast mode, and the pytest suite.
set -euo pipefail
cd "$(dirname "$0")/.."
# Each stage's wall time, and the run's, printed as it goes ("== name
# [mm:ss]") and summed up at the end: what CI's 20 minutes are spent on
stage_start=$SECONDS
stages=()
stage() {
  local now=$SECONDS
  [ -z "${stage_name:-}" ] || stages+=("$(printf '%-8s %3d:%02d' "$stage_name" $(((now - stage_start) / 60)) $(((now - stage_start) % 60)))")
  stage_name=$1
  stage_start=$now
  echo "== $2 [$((now / 60)):$(printf '%02d' $((now % 60)))]"
}
trap 'stage end "stage times"; printf "   %s\n" "${stages[@]}"; [ -z "${bench_pid:-}" ] || kill "$bench_pid" 2>/dev/null || true' EXIT
stage install "install and build (scripts/install.sh)"
bash scripts/install.sh
# The benchmark harness in its fast mode (the harness runs end to end;
# timings are not asserted) runs beside the doctests and the fuzz build: it
# compiles kernels on one core for about a minute, where the doctests' and
# the fuzz build's last files leave a core idle (bench/PERF_LOG.md 32). Its
# output is shown, and its exit status checked, after the fuzz build.
"${PYTHON:-python3}" bench/run.py --fast > build/bench_fast.log 2>&1 &
bench_pid=$!
stage ctest "doctest (ctest; bench/run.py --fast beside it)"
ctest --test-dir build --output-on-failure --parallel "$(nproc)"
stage fuzzbld "fuzz build (clang, libFuzzer + ASan + UBSan, build-fuzz/)"
# tests/fuzz/fuzz_nvdb.cpp (.nvdb) and fuzz_vdb.cpp (.vdb) with clang
# (libFuzzer + ASan + UBSan), in their own build directory. Seeds: the
# committed corpus (tests/fuzz/corpus/, what the campaign found:
# scripts/fuzz_campaign.sh), small generated grids and ../shared/data.
CC=clang-14 CXX=clang++-14 cmake -S . -B build-fuzz -G Ninja -DNVDB_BUILD_FUZZ=ON \
  -DNVDB_BUILD_TOOLS=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -gline-tables-only -DNDEBUG" \
  -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O2 -gline-tables-only -DNDEBUG" \
  -DPython_EXECUTABLE="$(command -v "${PYTHON:-python3}")" >/dev/null
cmake --build build-fuzz --target fuzz_nvdb fuzz_vdb
stage bench "bench (fast mode, started beside ctest: its output)"
bench_status=0
wait "$bench_pid" || bench_status=$?
cat build/bench_fast.log
[ "$bench_status" = 0 ] || { echo "bench/run.py --fast failed ($bench_status)"; exit 1; }
mkdir -p build-fuzz/seeds build-fuzz/corpus build-fuzz/seeds-vdb build-fuzz/corpus-vdb
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
stage fuzz "fuzz (short runs; NVDB_FUZZ_SECONDS=${NVDB_FUZZ_SECONDS:-20} each)"
shared="${NVDB_SHARED_DATA:-../shared/data}"
# The two fuzzers run side by side, one core each (fuzz_nvdb in the
# background; its exit status is waited for below: a crash fails the run).
# (-max_len: the typed seeds are 1.2-2.4 MB; the default 1 MiB would cut
# them short, and no quantized or Vec3f grid would reach the lookups)
build-fuzz/bin/fuzz_nvdb -max_total_time="${NVDB_FUZZ_SECONDS:-20}" -print_final_stats=1 -max_len=2500000 \
  build-fuzz/corpus $( [ -d tests/fuzz/corpus/nvdb ] && echo tests/fuzz/corpus/nvdb ) build-fuzz/seeds \
  $( [ -d "$shared" ] && echo "$shared" ) > build-fuzz/fuzz_nvdb.log 2>&1 &
fuzz_nvdb_pid=$!
# Small OpenVDB files from the generator (fog, random values, a level set,
# an empty grid; ~10-80 KB: a large file reads at a few per second). The
# shared files are the campaign's seeds (scripts/fuzz_campaign.sh).
for g in constant_8 random_8 cloud_8 sphere_ls_3 empty; do
  [ -f "build-fuzz/seeds-vdb/$g.vdb" ] ||
    build/bin/vdb2nvdb generate "$g" "build-fuzz/seeds-vdb/$g.vdb" >/dev/null
done
# OpenVDB's reader crashes on damaged files, by design contained in the
# reader's process (src/loader/vdb_import.cpp): the run goes on past a
# crash (fork mode), and every finding is triaged: a crash in our code, or
# one that the plugin does not turn into an error, fails the run
# (tests/fuzz/triage_vdb.py)
rm -rf build-fuzz/findings-vdb && mkdir -p build-fuzz/findings-vdb
build-fuzz/bin/fuzz_vdb -fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1 \
  -max_total_time="${NVDB_FUZZ_SECONDS:-20}" -rss_limit_mb=2048 -max_len=131072 \
  -artifact_prefix=build-fuzz/findings-vdb/ build-fuzz/corpus-vdb \
  $( [ -d tests/fuzz/corpus/vdb ] && echo tests/fuzz/corpus/vdb ) \
  build-fuzz/seeds-vdb > build-fuzz/fuzz_vdb.log 2>&1 || true
grep -E '^#[0-9]+: cov:' build-fuzz/fuzz_vdb.log | tail -n 1 || true
findings=(build-fuzz/findings-vdb/*)
if [ -e "${findings[0]}" ]; then
  "${PYTHON:-python3}" tests/fuzz/triage_vdb.py build-fuzz/bin/fuzz_vdb build "${findings[@]}"
else
  echo "fuzz_vdb: no findings"
fi
nvdb_status=0
wait "$fuzz_nvdb_pid" || nvdb_status=$?
tail -n 8 build-fuzz/fuzz_nvdb.log
[ "$nvdb_status" = 0 ] || { echo "fuzz_nvdb failed ($nvdb_status): build-fuzz/fuzz_nvdb.log"; exit 1; }
# pytest last: its summary line closes the run
stage pytest "pytest"
# One worker per core, each taking whole files (--dist loadfile: a file's
# module fixtures, its generated grids and renders, stay in one process;
# bench/PERF_LOG.md 28), the longest files first (tests/conftest.py's
# FILE_SECONDS; --no-loadscope-reorder keeps that order: PERF_LOG 34).
# NVDB_PYTEST_WORKERS=0 runs them in this process.
# --durations: the 20 slowest, where CI's time goes (bench/PERF_LOG.md 29)
"${PYTHON:-python3}" -m pytest -q tests -p no:cacheprovider \
  -n "${NVDB_PYTEST_WORKERS:-$(nproc)}" --dist loadfile --no-loadscope-reorder \
  --durations=20 "$@"
