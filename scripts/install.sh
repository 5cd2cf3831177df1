#!/usr/bin/env bash
# Installs what nanovdb-mitsuba needs on Debian 12 (run as root), then builds
# and installs it with pip (`pip install .`: the plugins, vdb2nvdb and
# nanovdb-render), building in build/ so that a second run only rebuilds
# what changed. Idempotent: packages already present are not fetched again.
#   --no-tests: leave out the test programs (the quickstart needs none), unless
#               build/ already builds them
#   --variants=V1;V2: build the plugins for these Mitsuba variants only (the
#               quickstart: the one nanovdb-render uses), unless build/ is a
#               test build; without it, all of the wheel's (pip install .)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_TESTS=ON
VARIANTS=""
for arg in "$@"; do
  case "$arg" in
    --no-tests) BUILD_TESTS=OFF ;;
    --variants=*) VARIANTS="${arg#--variants=}" ;;
    *) echo "install.sh: unknown option $arg" >&2; exit 2 ;;
  esac
done

APT_PACKAGES=(
  cmake ninja-build g++ pkg-config
  libnanovdb-dev      # NanoVDB 32.4 headers incl. PNanoVDB.h (the reference we translate)
  libopenvdb-dev libboost-dev libtbb-dev libimath-dev  # OpenVDB 10: test grids, vdb2nvdb
  libblosc-dev zlib1g-dev   # .nvdb codecs
  libllvm19           # Dr.Jit's LLVM backend fails with Debian's default libLLVM 14/15
)
# Only the tests use these (the quickstart, --no-tests, leaves them out)
TEST_APT_PACKAGES=(
  python3-venv        # tests/test_pip_install.py: a fresh virtual environment (ensurepip)
  doctest-dev
  clang-14 libclang-rt-14-dev  # libFuzzer + ASan/UBSan runtimes for tests/fuzz
)
# The build's requirements (pyproject.toml [build-system]) are installed here
# and the build uses them (--no-build-isolation): no second download.
PIP_PACKAGES=(mitsuba==3.9.1 drjit==1.5.0 nanobind==3.1.0 scikit-build-core==1.1.2 numpy==2.4.6)
# the tests and the benchmarks; pytest-xdist runs the test files on every core
TEST_PIP_PACKAGES=(pytest==9.2.0 pytest-xdist==3.8.0 execnet==2.1.2 matplotlib==3.11.2)

if grep -qs "^NVDB_BUILD_TESTS:BOOL=ON" build/CMakeCache.txt; then
  BUILD_TESTS=ON  # keep a test build a test build (no flip-flopping of build/)
fi
if [ "$BUILD_TESTS" = ON ]; then
  APT_PACKAGES+=("${TEST_APT_PACKAGES[@]}")
  PIP_PACKAGES+=("${TEST_PIP_PACKAGES[@]}")
fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "== apt-get install ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PYTHON=${PYTHON:-python3}
# Debian's own python3 ships without pip and is "externally managed" (PEP 668):
# install pip from Debian, and let it install into /usr/local as root.
if ! "$PYTHON" -m pip --version >/dev/null 2>&1; then
  echo "== apt-get install python3-pip"
  apt-get update -qq && apt-get install -y -qq --no-install-recommends python3-pip >/dev/null
fi
PIP_FLAGS=(--disable-pip-version-check)
if [ -f "$("$PYTHON" -c 'import sysconfig; print(sysconfig.get_path("stdlib"))')/EXTERNALLY-MANAGED" ]; then
  PIP_FLAGS+=(--break-system-packages)
fi
if ! "$PYTHON" - "${PIP_PACKAGES[@]}" <<'PY' 2>/dev/null
import importlib.metadata as md, sys
want = dict(p.split("==") for p in sys.argv[1:])
sys.exit(0 if all(md.version(k) == v for k, v in want.items()) else 1)
PY
then
  echo "== pip install ${PIP_PACKAGES[*]}"
  "$PYTHON" -m pip install -q "${PIP_FLAGS[@]}" "${PIP_PACKAGES[@]}"
fi

CHECK_VARIANTS=""
if [ "$BUILD_TESTS" = ON ]; then
  # The variants the tests run: every CPU variant (tests/conftest.py's
  # variants_all), and where a GPU is, every variant. Without a GPU no test
  # can run the CUDA variants: a test build leaves them out, and checks the
  # code of the GPU kit's (rgb, mono, spectral) with g++ -fsyntax-only
  # instead (NVDB_CHECK_VARIANTS: a quarter of the time that compiling them
  # takes; bench/PERF_LOG.md 30). scripts/gpu_kit_pack.sh builds them for
  # the kit. A plain `pip install .` builds all.
  read -r VARIANTS CHECK_VARIANTS < <("$PYTHON" -c 'import ctypes, mitsuba as mi
try:
    ctypes.CDLL("libcuda.so.1"); gpu = True
except OSError:
    gpu = False
cpu = [v for v in mi.variants() if not v.startswith("cuda")]
kit = [v for v in mi.variants() if v.startswith("cuda") and not v.endswith("polarized")]
print("-" if gpu else ";".join(cpu), "-" if gpu else ";".join(kit))')
  [ "$VARIANTS" != "-" ] || VARIANTS=""
  [ "$CHECK_VARIANTS" != "-" ] || CHECK_VARIANTS=""
fi

# One compile per core: ninja's default (cores + 2) makes a 2-core build
# ~15 % slower (the large files compete for caches and memory)
export CMAKE_BUILD_PARALLEL_LEVEL=${CMAKE_BUILD_PARALLEL_LEVEL:-$(nproc)}
echo "== pip install . (build in build/, tests ${BUILD_TESTS}, variants: ${VARIANTS:-all}${CHECK_VARIANTS:+; checked only: $CHECK_VARIANTS})"
# (not -q: pip prints the build's output when it fails; --config-settings, not -C: Debian 12's pip 23.0 lacks -C)
"$PYTHON" -m pip install "${PIP_FLAGS[@]}" --no-build-isolation --no-deps \
  --config-settings build-dir=build \
  --config-settings cmake.define.NVDB_BUILD_TESTS="$BUILD_TESTS" \
  --config-settings cmake.define.NVDB_VARIANTS="$VARIANTS" \
  --config-settings cmake.define.NVDB_CHECK_VARIANTS="$CHECK_VARIANTS" .
