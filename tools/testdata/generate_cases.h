// The synthetic volumes of `vdb2nvdb generate` (tools/vdb2nvdb/README.md),
// also the benchmarks' generated cases (bench/cases.py) and the converter
// tests' inputs (tests/test_vdb2nvdb.py).
//
// Every value is a function of its voxel coordinate (noise.h: hash-based
// noise, no std:: distributions), so the grids are the same on every platform
// and do not depend on thread scheduling; voxels are written leaf by leaf in
// parallel, so no dense copy of the volume is ever made.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <openvdb/openvdb.h>

namespace nvdb_testdata {

/// One line per case: name and description (for --help and `generate --list`).
std::vector<std::pair<std::string, std::string>> generate_cases();

/// Builds the grids of a case; std::invalid_argument (listing the cases) for
/// an unknown name.
openvdb::GridPtrVec make_case(const std::string &name);

} // namespace nvdb_testdata
