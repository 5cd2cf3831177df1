// Reading the input: the grids of a .vdb file (OpenVDB), or of a .nvdb file
// turned back into OpenVDB grids. Errors name the file.
#pragma once

#include <string>

#include <openvdb/openvdb.h>

namespace vdb2nvdb {

/// Every grid of a .vdb file, in file order.
openvdb::GridPtrVec read_vdb(const std::string &path);

/// A .nvdb file's grids as OpenVDB grids, through NanoVDB's own reader and
/// nanoToOpenVDB: a NanoVDB level set can then become a fog volume as an
/// OpenVDB one does (nanovdb-render does that with .nvdb level sets). Grids
/// that NanoVDB cannot turn back into OpenVDB grids (index grids, points)
/// are skipped with a note.
openvdb::GridPtrVec read_nvdb(const std::string &path);

/// read_nvdb for a name ending in .nvdb, read_vdb otherwise
openvdb::GridPtrVec read_input(const std::string &path);

} // namespace vdb2nvdb
