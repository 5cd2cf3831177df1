// Backend helpers shared by the read-for-read doctests (test_translation,
// test_value_types): starting a Dr.Jit backend, whether CUDA is there, and
// query coordinates as JIT arrays.
#pragma once

#include <nanovdb_drjit/pnanovdb.h>

#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <dlfcn.h>

#include <array>
#include <cstdint>
#include <vector>

namespace nvdb_test {

/// Whether libcuda loads (a GPU machine); the CUDA cases skip otherwise
inline bool cuda_available() {
    static const bool available = dlopen("libcuda.so.1", RTLD_LAZY | RTLD_LOCAL) != nullptr;
    return available;
}

// NVDB_TEST_CUDA=0: a build that leaves the CUDA variants out (NVDB_VARIANTS;
// a test build without a GPU, scripts/install.sh) compiles no CUDA case: its
// CUDA code is checked by nvdb_syntax_check (CMakeLists.txt), and the cases
// are reported as skipped
#ifndef NVDB_TEST_CUDA
#  define NVDB_TEST_CUDA 1
#endif
/// A CUDA test case's decorator: skipped without a GPU
#define NVDB_CUDA_CASE_SKIP doctest::skip(!NVDB_TEST_CUDA || !nvdb_test::cuda_available())

/// Starts the Dr.Jit backend of UInt32 (nothing for scalars)
template <typename UInt32> void init_backend() {
    if constexpr (drjit::is_jit_v<UInt32>) {
        jit_set_log_level_stderr(LogLevel::Warn);
        jit_init(1u << (uint32_t) drjit::backend_v<UInt32>);
    }
}

/// The first n coordinates as a JIT coordinate array
template <typename UInt32>
nanovdb_drjit::Coord<UInt32> jit_coords(const std::vector<std::array<int32_t, 3>> &coords,
                                        size_t n) {
    using Int32 = drjit::int32_array_t<UInt32>;
    std::vector<int32_t> x(n), y(n), z(n);
    for (size_t i = 0; i < n; ++i) {
        x[i] = coords[i][0]; y[i] = coords[i][1]; z[i] = coords[i][2];
    }
    return { drjit::load<Int32>(x.data(), n), drjit::load<Int32>(y.data(), n),
             drjit::load<Int32>(z.data(), n) };
}

} // namespace nvdb_test
