// vdb2nvdb generate: synthetic test volumes written as .vdb (OpenVDB) and,
// optionally, converted to .nvdb by the same pipeline as `vdb2nvdb IN OUT`.
#pragma once

#include <string>
#include <vector>

#include <openvdb/openvdb.h>

#include "convert.h"

namespace vdb2nvdb {

/// One line per case: name and description (for --help and `generate --list`).
std::vector<std::pair<std::string, std::string>> generate_cases();

/// Builds the grids of a case; Error (listing the cases) for an unknown name.
openvdb::GridPtrVec make_case(const std::string &name);

/// vdb2nvdb generate CASE OUT.vdb [OUT.nvdb]
int generate(const std::string &name, const std::string &out_vdb, const std::string &out_nvdb,
             const Options &opts);

} // namespace vdb2nvdb
