#!/usr/bin/env bash
# Runs the CUDA suite from an offline GPU kit (made by scripts/gpu_kit_pack.sh)
# on a machine with an NVIDIA GPU and no network: unpacks the kit, then runs
#   1. the doctest suites (test_translation: the translation against
#      PNanoVDB read for read on scalar, LLVM and CUDA; test_io: the loader),
#   2. the pytest suite, its variant-parametrized tests on the CUDA variants
#      (NVDB_TEST_VARIANTS, default cuda_ad_rgb,cuda_ad_spectral;
#      the GPU memory tests of tests/test_cuda.py; the >4 GiB grid),
#   3. the benchmarks: bench/run.py --gpu (nanovdbvolume vs gridvolume on
#      cuda_ad_rgb, and volpathlocal), bench/filters.py (every filter with
#      volpath and volpathlocal against volpath + gridvolume's hardware
#      trilinear, error at equal time: issue 19's CUDA targets),
#      bench/huge_sparse.py (a grid whose dense form does not fit on the GPU),
#      bench/emission.py (fire: emissiveheterogeneous against the same
#      medium without emission), bench/fire_nee.py (next-event estimation
#      toward the fire against collisions alone) and bench/optimize.py (prbvolpath on the
#      shared smoke through gridvolume and nanovdbvolume, trilinear and
#      stochastic_trilinear, and prbvolpathlocal through the tree's local
#      majorants with stochastic_trilinear, unfrozen and frozen),
# and writes logs and results to --out. Needs: Python 3 with numpy and pytest
# (the version the kit was packed for), an NVIDIA driver.
#
# Usage: bash gpu-kit/run.sh [--out DIR] [--home DIR]
#                            [--steps "doctest pytest bench filters huge emission fire_nee optimize"]
#                            [--limits "pytest=180 bench=100 ..."]
#                            [--bench-args "..."] [--filters-args "..."] [--huge-args "..."]
#                            [--emission-args "..."] [--optimize-args "..."]
#                            [-- PYTEST ARGS...]
# --limits gives steps a wall-clock limit in seconds (GNU timeout: the step
# and its child processes are stopped, its log kept, its exit code 124), so
# that one device call of fixed length runs every step it names.
set -uo pipefail
KIT=$(cd "$(dirname "$0")" && pwd)
OUT=$PWD/gpu-kit-results
HOME_DIR=${NVDB_KIT_HOME:-/tmp/nvdb-gpu-kit}
STEPS="doctest pytest bench filters huge emission fire_nee optimize"
BENCH_ARGS="--integrators volpath volpathlocal" FILTERS_ARGS="" HUGE_ARGS=""
EMISSION_ARGS="" OPTIMIZE_ARGS="" LIMITS=""
while [ $# -gt 0 ]; do
  case "$1" in
    --out) OUT=$2; shift 2 ;;
    --home) HOME_DIR=$2; shift 2 ;;
    --steps) STEPS=$2; shift 2 ;;
    --bench-args) BENCH_ARGS=$2; shift 2 ;;
    --filters-args) FILTERS_ARGS=$2; shift 2 ;;
    --huge-args) HUGE_ARGS=$2; shift 2 ;;
    --emission-args) EMISSION_ARGS=$2; shift 2 ;;
    --optimize-args) OPTIMIZE_ARGS=$2; shift 2 ;;
    --limits) LIMITS=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "unknown argument: $1 (see the header of this script)" >&2; exit 2 ;;
  esac
done
PYTEST_ARGS=("$@")
PYTHON=${PYTHON:-python3}
mkdir -p "$OUT" "$HOME_DIR"
OUT=$(cd "$OUT" && pwd)

# ---- Unpack (again only when the kit changed)
stamp=$(cat "$KIT"/*.tar.xz | cksum | cut -d' ' -f1)
if [ "$(cat "$HOME_DIR/.stamp" 2>/dev/null)" != "$stamp" ]; then
  rm -rf "$HOME_DIR"/{python,build,src}
  mkdir -p "$HOME_DIR/src"
  for t in python build; do tar -C "$HOME_DIR" -xJf "$KIT/$t.tar.xz" & done
  tar -C "$HOME_DIR/src" -xJf "$KIT/source.tar.xz" &
  wait
  echo "$stamp" > "$HOME_DIR/.stamp"
fi
H=$HOME_DIR
export PYTHONPATH="$H/python:$H/src/python${PYTHONPATH:+:$PYTHONPATH}"
export LD_LIBRARY_PATH="$H/build/lib:$H/python/drjit:$H/python/mitsuba${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export NVDB_BUILD_DIR="$H/build"
export NVDB_SHARED_DATA="$H/build/shared_data"
export NVDB_TEST_VARIANTS=${NVDB_TEST_VARIANTS:-cuda_ad_rgb,cuda_ad_spectral}
# each pytest failure's report as it happens (tests/conftest.py): a step
# stopped at its --limits prints no failure section of its own
export NVDB_FAILURE_LOG="$OUT/pytest_failures.log"
export PYTHONUNBUFFERED=1
NVDB_KIT_COMMIT="$(sed -n 's/^commit: //p' "$KIT/MANIFEST.txt") (GPU kit)"
export NVDB_KIT_COMMIT

declare -A RC
limit_of() {  # the --limits entry of a step (0: none)
  local kv
  for kv in $LIMITS; do [ "${kv%%=*}" = "$1" ] && { echo "${kv#*=}"; return; }; done
  echo 0
}
step() {  # step NAME COMMAND...: runs it, logs to $OUT/NAME.log, records its exit code
  local name=$1; shift
  local limit; limit=$(limit_of "$name")
  local note=""; [ "$limit" = 0 ] || note=" (limit $limit s)"
  echo "== $name: $*$note"
  local t0=$SECONDS
  if [ "$limit" != 0 ]; then
    # timeout runs programs, not shell functions: a function step runs in a
    # child bash that is given it (export -f; the variables it reads are
    # exported where it is defined)
    if declare -F "$1" > /dev/null; then
      export -f "$1"
      timeout --kill-after=10 "$limit" bash -c '"$@"' _ "$@" > "$OUT/$name.log" 2>&1
    else
      timeout --kill-after=10 "$limit" "$@" > "$OUT/$name.log" 2>&1
    fi
  else
    "$@" > "$OUT/$name.log" 2>&1
  fi
  RC[$name]=$?
  tail -n 25 "$OUT/$name.log"
  echo "== $name: exit ${RC[$name]} ($((SECONDS - t0)) s)"
}

{
  echo "kit: $(head -3 "$KIT/MANIFEST.txt" | tr '\n' ' ')"
  nvidia-smi --query-gpu=name,memory.total,memory.used,driver_version --format=csv,noheader || true
  uname -srm; ldd --version | head -1
  "$PYTHON" - <<'PY'
import sys, drjit as dr, mitsuba as mi
print("python", sys.version.split()[0], "| mitsuba", mi.__version__, mi.__file__)
print("drjit", dr.__version__, "| CUDA:", dr.has_backend(dr.JitBackend.CUDA),
      "| LLVM:", dr.has_backend(dr.JitBackend.LLVM))
PY
  echo "NVDB_TEST_VARIANTS=$NVDB_TEST_VARIANTS"
} 2>&1 | tee "$OUT/environment.txt"

cd "$H/src"
want() { case " $STEPS " in *" $1 "*) return 0 ;; *) return 1 ;; esac; }
if want doctest; then
  step doctest_translation "$H/build/bin/test_translation"
  step doctest_sampler "$H/build/bin/test_sampler"
  step doctest_io "$H/build/bin/test_io"
  step doctest_hdda "$H/build/bin/test_hdda"
  step doctest_majorant_walk "$H/build/bin/test_majorant_walk"
  step doctest_value_types "$H/build/bin/test_value_types"
fi
if want pytest; then
  # the GPU's own tests first (memory on the device, the >4 GiB grid): the
  # suite's order puts a file it has no CPU timing for last
  step pytest_cuda "$PYTHON" -m pytest tests/test_cuda.py -p no:cacheprovider -rs \
       --junitxml="$OUT/pytest_cuda.xml"
  # (the files that read what the kit does not carry: the README and docs,
  # pyproject.toml, the plugins' sources)
  step pytest "$PYTHON" -m pytest tests --ignore=tests/test_cuda.py \
       --ignore=tests/test_readme.py --ignore=tests/test_plugin_docs.py \
       --ignore=tests/test_pip_install.py --ignore=tests/test_marked_copies.py \
       -p no:cacheprovider -rs --durations=15 --junitxml="$OUT/pytest.xml" "${PYTEST_ARGS[@]}"
fi
if want bench; then
  # shellcheck disable=SC2086
  step bench "$PYTHON" bench/run.py --gpu --build "$H/build" --data "$H/bench-data" \
       --out "$OUT/bench" $BENCH_ARGS
fi
if want filters; then
  smoke="$NVDB_SHARED_DATA/openvdb_smoke1_fog.vdb"
  [ -f "$smoke" ] || smoke=""
  # shellcheck disable=SC2086
  step filters "$PYTHON" bench/filters.py --build "$H/build" --data "$H/bench-data" \
       --cases cloud cloudfield_400 sphere_fog_256 constant_300 ${smoke:+--vdb "$smoke"} \
       --variants cuda_ad_rgb --res 256 --spp 64 --ref-spp 4096 --runs 5 \
       --out "$OUT/bench/filters.md" $FILTERS_ARGS
fi
if want huge; then
  # shellcheck disable=SC2086
  step huge_sparse "$PYTHON" bench/huge_sparse.py --build "$H/build" --data "$H/bench-data" \
       --out "$OUT/bench" $HUGE_ARGS
fi

if want emission; then
  # shellcheck disable=SC2086
  step emission "$PYTHON" bench/emission.py --cases fireball --variants cuda_ad_rgb \
       --ref-variant cuda_ad_rgb --build "$H/build" --data "$H/bench-data/emission" \
       --out "$OUT/bench/emission.md" $EMISSION_ARGS
fi
if want fire_nee; then
  step fire_nee "$PYTHON" bench/fire_nee.py --cases fireball --variants cuda_ad_rgb \
       --ref-variant cuda_ad_rgb --build "$H/build" --data "$H/bench-data/emission" \
       --out "$OUT/bench/fire_nee.md"
fi
if want optimize; then
  optimize() {  # the shared smoke: prbvolpath through gridvolume, nanovdbvolume x 2 filters;
                # prbvolpathlocal (issue 36) through nanovdbvolume, stochastic_trilinear
    local smoke="$NVDB_SHARED_DATA/openvdb_smoke1_fog.vdb" d="$H/bench-data/optimize"
    [ -f "$smoke" ] || { echo "no $smoke: the kit was packed without ../shared/data"; return 1; }
    mkdir -p "$d"
    [ -f "$d/smoke.vol" ] || "$H/build/bin/vdb2nvdb" "$smoke" "$d/smoke.nvdb" --dense "$d/smoke.vol" || return 1
    local rc=0 o="$OUT/bench/optimize"
    # shellcheck disable=SC2086
    "$PYTHON" bench/optimize.py --variant cuda_ad_rgb --target "$d/smoke.vol" --plugin gridvolume \
        --reference "$d/smoke.vol" --out "$o" $OPTIMIZE_ARGS || rc=1
    for f in trilinear stochastic_trilinear; do
      # shellcheck disable=SC2086
      "$PYTHON" bench/optimize.py --variant cuda_ad_rgb --target "$d/smoke.nvdb" \
          --plugin nanovdbvolume --reference "$d/smoke.vol" --filter $f --out "$o" \
          $OPTIMIZE_ARGS || rc=1
    done
    # shellcheck disable=SC2086
    "$PYTHON" bench/optimize.py --variant cuda_ad_rgb --target "$d/smoke.nvdb" \
        --plugin nanovdbvolume --reference "$d/smoke.vol" --filter stochastic_trilinear \
        --integrator prbvolpathlocal --out "$o" $OPTIMIZE_ARGS || rc=1
    # ... and its steps frozen (dr.freeze; docs/differentiable.md "Frozen steps")
    # shellcheck disable=SC2086
    "$PYTHON" bench/optimize.py --variant cuda_ad_rgb --target "$d/smoke.nvdb" \
        --plugin nanovdbvolume --reference "$d/smoke.vol" --filter stochastic_trilinear \
        --integrator prbvolpathlocal --freeze --out "$o" $OPTIMIZE_ARGS || rc=1
    return $rc
  }
  export H OUT PYTHON OPTIMIZE_ARGS   # (what optimize reads, in step's child bash too)
  step optimize optimize
fi

echo "== summary" | tee "$OUT/summary.txt"
fail=0
for k in "${!RC[@]}"; do
  echo "$k: exit ${RC[$k]}" | tee -a "$OUT/summary.txt"
  [ "${RC[$k]}" = 0 ] || fail=1
done
exit $fail
