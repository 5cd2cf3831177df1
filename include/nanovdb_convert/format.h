// vdb2nvdb's messages: numbers, coordinates and grids as text, and the two
// ways of printing (progress on stdout, notes on stderr).
#pragma once

#include <cstdint>
#include <string>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// s in double quotes
std::string dq(const std::string &s);

/// 1234567 -> "1,234,567"
std::string fmt_count(uint64_t n);

/// "1,234,567 B (1.2 MiB)"
std::string fmt_bytes(uint64_t n);

/// "(x, y, z)"
std::string fmt_coord(const openvdb::Coord &c);

/// %.9g: a float's every digit
std::string fmt_float(double v);

std::string class_name(openvdb::GridClass c);

/// "name" (type, class)
std::string grid_summary(const openvdb::GridBase &g);

/// The grid_summary() of every grid, comma-separated; "(no grids)" for none
std::string list_grids(const openvdb::GridPtrVec &grids);

/// A progress line on stdout (not with --quiet)
void say(const Options &opts, const std::string &msg);

/// "vdb2nvdb: note: msg" on stderr
void note(const std::string &msg);

} // namespace vdb2nvdb
