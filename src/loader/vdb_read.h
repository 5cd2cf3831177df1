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
/// converted as vdb2nvdb converts it. Throws nanovdb_loader::Error, whose
/// message starts with "\"<path>\": ".
VdbGrid read_vdb_grid(const std::string &path, const std::string &selector);

/// The checks read_vdb_grid makes before OpenVDB reads a grid, for every
/// grid of the file: the header, the grid descriptors' offsets against the
/// file's size, and each tree root's tile and child counts against the
/// bytes of its grid (vdb2nvdb runs them before io::Stream reads it all).
/// False for a stream without grid offsets (nothing to check against);
/// throws nanovdb_loader::Error for a damaged file.
bool check_vdb_structure(const std::string &path);

} // namespace nanovdb_loader
