// The test volumes of grids.h in the other value types nanovdbvolume reads.
//
// Fp4, Fp8, Fp16 and FpN grids are written by NanoVDB's own converter
// (nanovdb::openToNanoVDB with the build type; FpN with its default
// absolute-difference oracle, 0.01 for fog volumes). Debian's NanoVDB 32.4
// cannot build Half grids: to_half() rewrites a float grid into PNanoVDB's
// Half layout (pnanovdb_grid_type_constants[PNANOVDB_GRID_TYPE_HALF]), every
// value rounded to nearest even by the CPU's F16C instruction, so that the
// reference rounding is not ours. Vec3f grids hold vec3_of(v) = (v, v / 2 +
// 0.1, v^2) for each value v of the float grid (voxels and tiles, active or
// not), converted from an openvdb::Vec3SGrid by openToNanoVDB.
#pragma once

#include "grids.h"

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace nvdb_test {

/// "float", "fp4", "fp8", "fp16", "fpn", "half", "vec3f"
const std::vector<std::string> &type_names();

/// NanoVDB's GridType value of a type name
uint32_t grid_type_of(const std::string &type);

/// A grid of `type` holding make_vdb_grid(name, scale), as 32-bit words,
/// together with the float grid it was made from (same topology)
struct TypedGrid {
    std::string name, type;
    uint32_t grid_type = 0;
    std::vector<uint32_t> words;
    uint64_t bytes = 0;
    nanovdb::GridHandle<nanovdb::HostBuffer> float_grid;
    nanovdb::GridHandle<nanovdb::HostBuffer> handle; ///< NanoVDB's grid (not for half)

    /// The value at ijk as NanoVDB's accessor decodes it (Fp*: NanoGrid<FpX>;
    /// half: the float grid's value rounded by F16C)
    std::function<float(const nanovdb::Coord &)> reference() const;
    /// vec3f: the 3 channels as NanoVDB's accessor reads them
    std::function<void(const nanovdb::Coord &, float *)> reference3() const;
};

/// Throws std::invalid_argument for "fpn" on a grid without leaves
TypedGrid make_typed_grid(const std::string &name, const std::string &type, int scale = 1);

/// Whether make_typed_grid(name, type) can be built
bool has_typed_grid(const std::string &name, const std::string &type);

/// The colour a vec3f test grid holds where the float grid holds v
std::array<float, 3> vec3_of(float v);

/// IEEE binary16 conversions by the CPU (F16C), round to nearest even
uint16_t f16c_from_float(float f);
float f16c_to_float(uint16_t h);

/// A float grid rewritten in PNanoVDB's Half layout (see above)
std::vector<uint32_t> to_half(const nanovdb::NanoGrid<float> &grid, uint64_t &bytes);

} // namespace nvdb_test
