#!/bin/sh
# The in-tree check (ctest: cmake_intree_link): configure the stand-in
# mitsuba3 checkout (CMakeLists.txt here), build the three plugins and the
# libraries they link, for one variant at -O0, in a temporary directory,
# then dlopen each plugin with every symbol resolved (RTLD_NOW).
# Fails when the in-tree branch forgets a library the plugins call: the
# link (-Wl,--no-undefined) or the load reports the missing symbol.
#   sh tests/cmake_intree/check.sh [PYTHON]      (from anywhere)
# NVDB_INTREE_ALL=1 also builds the .vdb reader and its OpenVDB libraries
# (the configure step checks they are defined and where the reader goes;
# building them costs about as much again as the plugins).
# NVDB_INTREE_KEEP=1 keeps the build directory and prints its path.
set -eu
src=$(cd "$(dirname "$0")/../.." && pwd)
python=${1:-${PYTHON:-python3}}
tmp=$(mktemp -d "${TMPDIR:-/tmp}/nvdb-intree.XXXXXX")
if [ "${NVDB_INTREE_KEEP:-0}" = 1 ]; then
  echo "build directory: $tmp"
else
  trap 'rm -rf "$tmp"' EXIT
fi
generator=Ninja
command -v ninja >/dev/null 2>&1 || generator="Unix Makefiles"
# -O0: the check links, it does not time; one variant (plugin_variants.h)
cmake -S "$src/tests/cmake_intree" -B "$tmp" -G "$generator" \
  -DNVDB_SOURCE_DIR="$src" -DPython_EXECUTABLE="$(command -v "$python")" \
  -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS_DEBUG=-O0 -DNVDB_VARIANTS=scalar_rgb >"$tmp/configure.log" 2>&1 ||
  { cat "$tmp/configure.log"; exit 1; }
grep "in-tree check:" "$tmp/configure.log"
if [ "${NVDB_INTREE_ALL:-0}" = 1 ]; then
  cmake --build "$tmp"
  test -x "$tmp/plugins/nanovdb-vdb-reader" || grep -q "OpenVDB: OFF" "$tmp/configure.log"
else
  cmake --build "$tmp" --target nanovdbvolume volpathlocal emissiveheterogeneous
fi
"$python" - "$tmp/plugins" <<'EOF'
import ctypes, os, sys
plugins = sys.argv[1]
for name in ("nanovdbvolume", "volpathlocal", "emissiveheterogeneous"):
    ctypes.CDLL(os.path.join(plugins, name + ".so"))  # RTLD_NOW: every symbol resolved
    print("in-tree check: loaded", name)
EOF
