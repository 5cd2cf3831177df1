// The conversion by NanoVDB's OpenToNanoVDB. See to_nano.h.

#include <nanovdb_convert/to_nano.h>

#include <type_traits>

#include <nanovdb/util/GridChecksum.h>
#include <nanovdb/util/OpenToNanoVDB.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>

namespace vdb2nvdb {

using openvdb::FloatGrid;

namespace {

template <typename BuildT>
Handle convert_as(const FloatGrid &grid, const Options &opts) {
    nanovdb::OpenToNanoVDB<float, BuildT, nanovdb::AbsDiff> converter;
    if constexpr (std::is_same_v<BuildT, nanovdb::FpN>)
        if (opts.tolerance >= 0.f)
            converter.oracle().setTolerance(opts.tolerance);
    // Full checksum: the read-back check covers every byte of the grid
    return converter(grid, nanovdb::StatsMode::Default, nanovdb::ChecksumMode::Full, 0);
}

} // namespace

Handle convert_one(const FloatGrid &grid, Quantize q, const Options &opts) {
    try {
        switch (q) {
            case Quantize::Float: return convert_as<float>(grid, opts);
            case Quantize::Fp4: return convert_as<nanovdb::Fp4>(grid, opts);
            case Quantize::Fp8: return convert_as<nanovdb::Fp8>(grid, opts);
            case Quantize::Fp16: return convert_as<nanovdb::Fp16>(grid, opts);
            case Quantize::FpN: return convert_as<nanovdb::FpN>(grid, opts);
        }
    } catch (const std::exception &e) {
        throw Error("grid " + dq(grid.getName()) + ": NanoVDB conversion failed: " + e.what());
    }
    throw Error("unknown quantization");
}

Handle convert_vec3(const openvdb::Vec3SGrid &grid) {
    try {
        return nanovdb::openToNanoVDB<nanovdb::HostBuffer, openvdb::Vec3STree, nanovdb::Vec3f>(
            grid, nanovdb::StatsMode::Default, nanovdb::ChecksumMode::Full, 0);
    } catch (const std::exception &e) {
        throw Error("grid " + dq(grid.getName()) + ": NanoVDB conversion failed: " + e.what());
    }
}

Quantize effective_quantize(const FloatGrid &grid, Quantize q) {
    if (q == Quantize::FpN && grid.tree().leafCount() == 0)
        return Quantize::Fp16;
    return q;
}

void corrupt_for_test(Handle &handle) {
    auto *grid = handle.grid<float>();
    if (!grid)
        throw Error("--corrupt-for-test works on float output only");
    auto *leaf = grid->tree().getFirstLeaf();
    for (uint32_t i = 0; i < grid->tree().nodeCount(0); ++i)
        leaf[i].data()->mValues[0] += 1.0f;
    nanovdb::updateChecksum(*grid, nanovdb::ChecksumMode::Full);
}

} // namespace vdb2nvdb
