// vdb2nvdb's pipelines: conversion of OpenVDB float and vec3s grids to
// NanoVDB, with verification of the written file against OpenVDB, statistics
// and the dense Mitsuba .vol export; and the check of an existing file.
//
// Conventions (as in src/volumes/grid_nanovdb.cpp): values sit at integer
// index coordinates; index bounding boxes are inclusive on the upper end
// ([min, max]); a voxel's cell is [ijk - 0.5, ijk + 0.5] in index space.
#pragma once

#include <string>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// vdb2nvdb IN.vdb OUT.nvdb: reads `in`, converts, writes `out`. Returns an
/// exit code; throws Error for bad input (nothing is left at `out` then).
int convert_file(const std::string &in, const std::string &out, const Options &opts);

/// The same for grids already in memory (the generator); `label` names their
/// source in messages. The grids may be modified (level set -> fog).
int convert_grids(openvdb::GridPtrVec grids, const std::string &label,
                  const std::string &out, const Options &opts);

/// vdb2nvdb --verify-only IN.vdb OUT.nvdb: checks an existing .nvdb against
/// the .vdb it was converted from with the same options.
int verify_only(const std::string &in, const std::string &nvdb, const Options &opts);

} // namespace vdb2nvdb
