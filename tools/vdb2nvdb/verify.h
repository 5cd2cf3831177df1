// The written file against OpenVDB (after the fog conversion): --verify's
// sampled comparison, and --probe's values at chosen points.
#pragma once

#include <string>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/handle.h>
#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// --verify for a float grid: NanoVDB's GridValidator, the whole-grid
/// properties (name, background, active voxel count, bbox, class, transform),
/// then opts.verify samples (active voxels and tiles, the bbox grown by 2,
/// outside it up to the int32 extremes): values bit for bit (float) or within
/// the quantization bound, and active states. Mismatches go to stderr (the
/// first 10); Error if `nano` is not a float grid type.
bool verify_float(const openvdb::FloatGrid &vdb, const Handle &nano, const std::string &name,
                  const Options &opts);

/// --verify for vec3s -> Vec3f: every sampled value bit for bit (3 floats)
/// and its active state, at random active voxels and points around the box
bool verify_vec3(const openvdb::Vec3SGrid &vdb, const nanovdb::NanoGrid<nanovdb::Vec3f> &nano,
                 const std::string &name, const Options &opts);

/// --probe: one line per point with OpenVDB's and the written file's value
/// and active state
void print_probes(const openvdb::FloatGrid &vdb, const Handle &nano, const std::string &name,
                  const Options &opts);

} // namespace vdb2nvdb
