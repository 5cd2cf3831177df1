// src/loader/vdb_read.h -- an OpenVDB file's grid read and converted in THIS
// process, with OpenVDB (Debian's libopenvdb-dev).
//
// OpenVDB's reader trusts its stream: corrupt bytes reach malloc and free
// with garbage sizes. So nothing that a user's process loads calls this.
// nanovdbvolume reads a .vdb through nanovdb_loader::import_vdb_grid
// (include/nanovdb_loader/vdb_import.h), which runs this function in a
// separate process, nanovdb-vdb-reader (vdb_reader_main.cpp), under a
// memory budget (vdb_reader_budget.h). The fuzzer (tests/fuzz/fuzz_vdb.cpp)
// runs it in process, under ASan.
#pragma once

#include <nanovdb_loader/vdb_import.h>

namespace nanovdb_loader {

/// The grid `selector` of the .vdb file at `path` (vdb_import.h's rule),
/// converted as vdb2nvdb converts it (a level set made a fog volume unless
/// fog_level_sets is false: vdb2nvdb --keep-level-sets). Throws
/// nanovdb_loader::Error, whose message starts with "\"<path>\": ".
VdbGrid read_vdb_grid(const std::string &path, const std::string &selector,
                      bool fog_level_sets = true);

/// Every grid of the .vdb file at `path`: name, type and class from the
/// grid descriptors and metadata (no voxels read), after the same checks
/// of the header and descriptors as read_vdb_grid.
std::vector<VdbGridInfo> read_vdb_listing(const std::string &path);

/// Grid `index` of the NanoVDB file at `path`, a level set, made a fog
/// volume as vdb2nvdb makes one of a .nvdb input: NanoVDB's own reader,
/// nanoToOpenVDB, then the same preparation and conversion as
/// read_vdb_grid. Error for a grid that is not a float (or Fp) level set.
VdbGrid read_nvdb_level_set_as_fog(const std::string &path, uint32_t index);

/// The checks read_vdb_grid makes before OpenVDB reads a grid, for every
/// grid of the file: the header, the grid descriptors' offsets against the
/// file's size, and each tree root's tile and child counts against the
/// bytes of its grid (vdb2nvdb runs them before io::Stream reads it all).
/// False for a stream without grid offsets (nothing to check against);
/// throws nanovdb_loader::Error for a damaged file.
bool check_vdb_structure(const std::string &path);

} // namespace nanovdb_loader
