// vdb2nvdb generate: synthetic test volumes (tools/testdata/generate_cases.h)
// written as .vdb (OpenVDB) and, optionally, converted to .nvdb by the same
// pipeline as `vdb2nvdb IN OUT`.
#pragma once

#include <string>

#include "convert.h"

namespace vdb2nvdb {

/// vdb2nvdb generate CASE OUT.vdb [OUT.nvdb]; Error (ExitUsage, listing the
/// cases) for an unknown case.
int generate(const std::string &name, const std::string &out_vdb, const std::string &out_nvdb,
             const Options &opts);

} // namespace vdb2nvdb
