// The conversion itself: NanoVDB's own nanovdb::OpenToNanoVDB, float grids
// as float or quantized, vec3s grids as Vec3f, with a full checksum.
#pragma once

#include <openvdb/openvdb.h>

#include <nanovdb_convert/handle.h>
#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// A float grid as NanoVDB grid of q (FpN: with --tolerance when given).
Handle convert_one(const openvdb::FloatGrid &grid, Quantize q, const Options &opts);

/// A vec3s grid as NanoVDB's Vec3f (three floats per value, bit for bit)
Handle convert_vec3(const openvdb::Vec3SGrid &grid);

/// NanoVDB 32.4's FpN encoder indexes its leaf array without checking that
/// there is one (OpenToNanoVDB::compression: mArray0[size-1]), so a grid
/// without leaf nodes is written as Fp16 instead: it has no quantized values.
Quantize effective_quantize(const openvdb::FloatGrid &grid, Quantize q);

/// Adds 1 to the first value of every leaf and recomputes the checksum: a
/// stand-in for a conversion bug, which only the value comparison can catch.
void corrupt_for_test(Handle &handle);

} // namespace vdb2nvdb
