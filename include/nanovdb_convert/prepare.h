// Choosing the grids to convert (--grid, or every float and vec3s grid) and
// preparing them: a level set becomes a fog volume unless --keep-level-sets.
#pragma once

#include <string>
#include <vector>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// A grid chosen for conversion: float (grid) or vec3s (vec)
struct Prepared {
    openvdb::FloatGrid::Ptr grid; ///< after the fog conversion, if any (null: a vec3s grid)
    openvdb::Vec3SGrid::Ptr vec;  ///< a vec3s grid: written as Vec3f, never quantized
    std::string name;

    const openvdb::GridBase &base() const {
        return vec ? static_cast<const openvdb::GridBase &>(*vec)
                   : static_cast<const openvdb::GridBase &>(*grid);
    }
    openvdb::GridClass source_class;
    bool fogged = false;
};

/// The grids of `all` to convert, in file order; Error (naming `label`, the
/// source, and listing its grids) for a missing or unsupported --grid, a
/// non-affine transform or nothing to convert. Level sets in `all` are
/// turned into fog volumes in place.
std::vector<Prepared> select_and_prepare(openvdb::GridPtrVec &all, const std::string &label,
                                         const Options &opts);

} // namespace vdb2nvdb
