// A NanoVDB grid in memory (NanoVDB's GridHandle), and the dispatch on the
// float value types vdb2nvdb writes.
#pragma once

#include <string>

#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridHandle.h>
#include <nanovdb/util/HostBuffer.h>

#include <nanovdb_convert/error.h>

namespace vdb2nvdb {

using Handle = nanovdb::GridHandle<nanovdb::HostBuffer>;

/// Calls f(grid) with the handle's typed grid: float, Fp4, Fp8, Fp16 or FpN;
/// Error naming grid `name` for any other type.
template <typename F> void with_grid(const Handle &h, const std::string &name, F &&f) {
    if (auto *g = h.grid<float>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp4>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp8>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp16>()) f(*g);
    else if (auto *g = h.grid<nanovdb::FpN>()) f(*g);
    else
        throw Error("grid \"" + name + "\" in the written file has type " +
                    std::string(nanovdb::toStr(h.gridType())) + ", expected a float grid");
}

} // namespace vdb2nvdb
