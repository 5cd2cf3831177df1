// The test suite's named volumes: float grids built with OpenVDB
// (openvdb::FloatGrid, tiles added through tree().addTile(level, ...) so that
// every NanoVDB node level and root tiles occur). tests/grids.h converts them
// with NanoVDB's own openToNanoVDB; they are the independent inputs of the
// doctest suites (read for read against PNanoVDB) and the pytest suites
// (nvdb_make_test_grid: nanovdbvolume against Mitsuba's gridvolume).
//
// All grids: voxel size 1, identity transform (except noisy_cloud), grid
// class fog volume, grid name = case name. Values sit at integer index
// coordinates; index bounding boxes are inclusive on the upper end.
#pragma once

#include <string>
#include <vector>

#include <openvdb/openvdb.h>

namespace nvdb_testdata {

/// Names of all cases, in a stable order.
const std::vector<std::string> &grid_names();

/// Builds the named case with OpenVDB. `scale` (>= 1) multiplies the linear
/// size of the cases where that makes sense (fog_sphere, noisy_cloud,
/// constant_cube, random_cube, nonzero_background); the others ignore it.
/// Throws std::invalid_argument for an unknown name (listing the valid names)
/// or a scale below 1.
openvdb::FloatGrid::Ptr make_vdb_grid(const std::string &name, int scale = 1);

} // namespace nvdb_testdata
