// What a file holds: vdb2nvdb --list, and the per-grid lines that --stats
// repeats.
#pragma once

#include <string>

#include <openvdb/openvdb.h>

namespace vdb2nvdb {

/// The lines under a grid's row in --list: where it lies in world space (the
/// active voxels' cells through the transform), the transform, the values.
/// `box` is the grid's active index bbox.
std::string grid_details(const openvdb::GridBase &g, const openvdb::CoordBBox &box);

/// vdb2nvdb --list IN.vdb
int list_file(const std::string &in);

} // namespace vdb2nvdb
