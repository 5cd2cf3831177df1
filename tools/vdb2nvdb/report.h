// What was written, grid by grid: the one-line summary of each conversion
// and the table of --stats.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/handle.h>

namespace vdb2nvdb {

struct GridReport {
    std::string name, type, cls;
    uint64_t active = 0;
    openvdb::CoordBBox bbox;              // empty for an empty grid
    uint32_t nodes[3] = { 0, 0, 0 };      // leaf, lower, upper
    uint32_t tiles[3] = { 0, 0, 0 };      // active tiles: lower, upper, root
    uint64_t grid_bytes = 0, leaf_bytes = 0;
    double convert_ms = 0;
    std::string details; // grid_details(): world bbox, transform, value range
};

/// The counts and sizes of a written grid (type, active voxels, bbox, nodes,
/// tiles, bytes); name, class, details and time are the caller's.
GridReport report_of(const Handle &h);

/// --stats: the table of every grid of `out`, a file of file_size bytes
void print_stats(const std::vector<GridReport> &reports, uint64_t file_size,
                 const std::string &out);

} // namespace vdb2nvdb
