#!/usr/bin/env bash
# Packs an offline GPU kit: everything the CUDA suite and the benchmarks need
# on a machine with an NVIDIA GPU and no network (a cluster's GPU node, a
# lent test machine), in one folder of at most ~60 MB:
#
#   gpu-kit/python.tar.xz   mitsuba + drjit for the target Python (pip
#                           wheels, unpacked; headers, stubs and unused
#                           variant modules removed)
#   gpu-kit/build.tar.xz    build/plugins/{nanovdbvolume,volpathlocal,emissiveheterogeneous}.so,
#                           build/lib/nanovdb_grid_list.so, the test and tool
#                           binaries (doctest suites, grid generators,
#                           vdb2nvdb, nanovdb-vdb-reader: the plugin reads
#                           .vdb files through it), the shared libraries they need that a
#                           stock Linux lacks (OpenVDB, TBB, Blosc, ...), and
#                           the real volumes of ../shared/data if present
#   gpu-kit/source.tar.xz   this checkout's tests/, bench/, scenes/, scripts/,
#                           python/ (the nanovdb_mitsuba package the tests use)
#   gpu-kit/MANIFEST.txt    what is inside, versions, sizes, commit
#
# Usage: bash scripts/gpu_kit_pack.sh [--python 3.12] [--variants "cuda_ad_rgb ..."] [--out DIR]
#   --python    the GPU machine's Python (X.Y): the wheels are downloaded
#               for it (the plugin and binaries do not depend on Python)
#   --variants  Mitsuba variant modules to keep (default: scalar_rgb,
#               llvm_ad_rgb and cuda_ad_{rgb,spectral})
#   --out       the kit folder (default gpu-kit/, git-ignored)
#
# A test build without a GPU has no CUDA variants (scripts/install.sh): the
# kit's are then built in build-kit/ first (about 10 minutes on 2 cores).
#
# Then copy the kit (and nothing else) to the GPU machine and run
#   bash gpu-kit/run.sh            (= scripts/gpu_kit_run.sh)
# Check a kit here first with the LLVM variant:
#   bash scripts/gpu_kit_pack.sh --python 3.11 --out /tmp/kit &&
#   NVDB_TEST_VARIANTS=llvm_ad_rgb bash /tmp/kit/run.sh --steps "doctest pytest"
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

PYVER=3.12
# llvm_ad_rgb: the render command's and the sequences' variant, which their
# tests run on; cuda_ad_mono is left out so that the kit (~45 MB) and the
# working tree (~20 MB) fit the 64 MiB a device call carries
VARIANTS="scalar_rgb llvm_ad_rgb cuda_ad_rgb cuda_ad_spectral"
OUT=gpu-kit
while [ $# -gt 0 ]; do
  case "$1" in
    --python) PYVER=$2; shift 2 ;;
    --variants) VARIANTS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    *) echo "unknown argument: $1" >&2; exit 2 ;;
  esac
done
PYTHON=${PYTHON:-python3}
BUILD=${NVDB_BUILD_DIR:-build}
MI_VERSION=3.9.1
DR_VERSION=1.5.0
CACHE=${NVDB_KIT_CACHE:-$HOME/.cache/nvdb-kit}
XZ=(xz -T0 -9)

[ -f "$BUILD/plugins/nanovdbvolume.so" ] || { echo "build first: bash scripts/install.sh" >&2; exit 1; }
# A test build on a machine without a GPU leaves the CUDA variants out (it
# only checks their code: scripts/install.sh). Then the kit's variants are
# built here, in build-kit/ (the plugins, test programs and tools).
if grep -qs '^NVDB_VARIANTS:STRING=.' "$BUILD/CMakeCache.txt" &&
   ! grep -qs '^NVDB_VARIANTS:STRING=.*cuda_ad_rgb' "$BUILD/CMakeCache.txt"; then
  BUILD=build-kit
  echo "== $BUILD/: the kit's variants (${VARIANTS}), which the test build left out in part"
  cmake -S . -B "$BUILD" -G Ninja -DNVDB_BUILD_TESTS=ON -DNVDB_VARIANTS="${VARIANTS// /;}" \
    -DPython_EXECUTABLE="$(command -v "$PYTHON")" >/dev/null
  CMAKE_BUILD_PARALLEL_LEVEL=${CMAKE_BUILD_PARALLEL_LEVEL:-$(nproc)} cmake --build "$BUILD"
fi
rm -rf "$OUT"
mkdir -p "$OUT" "$CACHE/wheels"
STAGE=$(mktemp -d)
trap 'rm -rf "$STAGE"' EXIT

# ---- 1. Mitsuba and Dr.Jit for the target Python (cached: compressing takes a minute)
tag=cp${PYVER/./}
# Mitsuba plugins that nothing in the suite or the benchmarks loads
# (Gaussian splats, curves, SDFs, sky models, hair, principled and
# conductor BSDFs, other integrators, emitters and sensors: 38 MB): the kit
# travels beside the working tree, 64 MiB in all
UNUSED_PLUGINS="ellipsoids ellipsoidsmesh bsplinecurve linearcurve sdfgrid sunsky timed_sunsky
  hair measured_polarized principled principledthin pplastic ptracer cylinder direct
  roughconductor aov distant thinlens projector conductor bumpmap"
key=$(echo "$tag $MI_VERSION $DR_VERSION $VARIANTS $UNUSED_PLUGINS" | sha1sum | cut -c1-12)
py_tar="$CACHE/python-$tag-$key.tar.xz"
if [ ! -f "$py_tar" ]; then
  echo "== downloading mitsuba $MI_VERSION and drjit $DR_VERSION wheels for $tag"
  "$PYTHON" -m pip download -q --disable-pip-version-check --no-deps --only-binary=:all: \
    --python-version "$PYVER" --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$CACHE/wheels" "mitsuba==$MI_VERSION" "drjit==$DR_VERSION"
  mkdir -p "$STAGE/python"
  for w in "$CACHE"/wheels/mitsuba-$MI_VERSION-$tag-*.whl "$CACHE"/wheels/drjit-$DR_VERSION-$tag-*.whl; do
    [ -f "$w" ] || { echo "no $tag wheel found in $CACHE/wheels" >&2; exit 1; }
    (cd "$STAGE/python" && "$PYTHON" -m zipfile -e "$w" .)
  done
  # Not needed to run: C++ headers, CMake/pkg-config files, type stubs, and
  # the variant modules not asked for (each plugin .so holds every variant,
  # so all plugins stay).
  (cd "$STAGE/python" &&
   rm -rf mitsuba/include drjit/include mitsuba/cmake drjit/cmake mitsuba/pkgconfig \
          mitsuba/mitsuba_stubs ./*.dist-info/RECORD &&
   find . -name '*.pyi' -delete &&
   for p in $UNUSED_PLUGINS; do
     rm -f mitsuba/plugins/$p.so
   done &&
   for m in mitsuba/scalar_*.cpython-*.so mitsuba/llvm_*.cpython-*.so mitsuba/cuda_*.cpython-*.so; do
     v=$(basename "$m"); v=${v%%.cpython*}
     case " $VARIANTS " in *" $v "*) ;; *) rm -f "$m" ;; esac
   done)
  echo "== compressing python/ ($(du -sh "$STAGE/python" | cut -f1))"
  tar -C "$STAGE" -cf - python | "${XZ[@]}" > "$py_tar.tmp"
  mv "$py_tar.tmp" "$py_tar"
  rm -rf "$STAGE/python"
fi
cp "$py_tar" "$OUT/python.tar.xz"

# ---- 2. The built plugin and binaries, with the shared libraries they need
mkdir -p "$STAGE/build/plugins" "$STAGE/build/bin" "$STAGE/build/lib"
cp "$BUILD/plugins/nanovdbvolume.so" "$BUILD/plugins/volpathlocal.so" \
   "$BUILD/plugins/emissiveheterogeneous.so" "$STAGE/build/plugins/"
bins=(test_translation test_sampler test_hdda test_majorant_walk test_value_types test_io nvdb_make_test_grid
      nvdb_make_stability_grid nvdb_big_grid vdb2nvdb nanovdb-vdb-reader)
for b in "${bins[@]}"; do
  [ -x "$BUILD/bin/$b" ] && cp "$BUILD/bin/$b" "$STAGE/build/bin/"
done
# the grid listing that nanovdb_mitsuba.files loads with ctypes (the render
# command, sequences, fire and the benchmarks' .vdb cases list grids with it)
cp "$BUILD/lib/nanovdb_grid_list.so" "$STAGE/build/lib/"
# Libraries: what ldd resolves outside the C/C++ runtime (which every Linux
# has, newer on the GPU machine than here) and outside the Mitsuba/Dr.Jit
# wheels (in python/).
skip='^(linux-vdso|ld-linux|libc\.|libm\.|libdl\.|libpthread\.|librt\.|libstdc\+\+|libgcc_s)'
for f in "$STAGE"/build/plugins/*.so "$STAGE"/build/bin/* "$STAGE"/build/lib/nanovdb_grid_list.so; do
  ldd "$f" | awk '$3 ~ /^\// {print $1, $3}'
done | sort -u | while read -r name path; do
  [[ "$name" =~ $skip ]] && continue
  [[ "$path" == *site-packages* || "$path" == *dist-packages* ]] && continue
  cp -L "$path" "$STAGE/build/lib/$name"
done
strip --strip-unneeded "$STAGE"/build/lib/*.so* "$STAGE"/build/bin/* 2>/dev/null || true
SHARED=${NVDB_SHARED_DATA:-$ROOT/../shared/data}
if [ -d "$SHARED" ]; then
  cp -r "$SHARED" "$STAGE/build/shared_data"
fi
echo "== compressing build/ ($(du -sh "$STAGE/build" | cut -f1))"
tar -C "$STAGE" -cf - build | "${XZ[@]}" > "$OUT/build.tar.xz"

# ---- 3. The sources the suite runs from: the working tree as it is (tracked
# files and new ones that git does not ignore)
git ls-files -z --cached --others --exclude-standard -- tests bench scenes scripts python CMakeLists.txt |
  grep -zv '^bench/results/' |
  tar --null -T - -cf - | "${XZ[@]}" > "$OUT/source.tar.xz"
cp scripts/gpu_kit_run.sh "$OUT/run.sh"

# ---- 4. Manifest
{
  echo "nanovdb-mitsuba GPU kit, packed $(date -u '+%Y-%m-%d %H:%M UTC') on $(uname -n)"
  echo "commit: $(git rev-parse --short HEAD) $(git diff --quiet HEAD -- . ':!bench/results' || echo '(+ uncommitted changes)')"
  echo "python: $tag; mitsuba $MI_VERSION, drjit $DR_VERSION; variants: $VARIANTS"
  echo "build: $(ls "$STAGE/build/bin" | tr '\n' ' ')"
  echo "libraries: $(ls "$STAGE/build/lib" | tr '\n' ' ')"
  echo "shared data: $([ -d "$STAGE/build/shared_data" ] && ls "$STAGE/build/shared_data" | wc -l || echo 0) files"
  echo "files:"
  (cd "$OUT" && ls -l --block-size=1 | awk 'NR>1 {printf "  %-16s %12d\n", $9, $5}')
} > "$OUT/MANIFEST.txt"
total=$(du -cb "$OUT"/* | tail -1 | cut -f1)
echo "total: $total bytes" >> "$OUT/MANIFEST.txt"
cat "$OUT/MANIFEST.txt"
if [ "$total" -gt $((60 * 1000 * 1000)) ]; then
  echo "the kit is larger than 60 MB" >&2
  exit 1
fi
