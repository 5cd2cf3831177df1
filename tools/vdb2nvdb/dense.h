// The dense export (--dense): a grid's active index box as a Mitsuba .vol
// file (version 3, float32, 1 or 3 channels), the baseline for gridvolume.
#pragma once

#include <cstdint>
#include <string>

#include <openvdb/openvdb.h>

#include <nanovdb_convert/handle.h>
#include <nanovdb_convert/options.h>

namespace vdb2nvdb {

/// An inclusive index box [min, max] and the channels of its voxels
struct DenseBox {
    openvdb::Coord min{ 0 }, max{ 0 };
    uint64_t voxels() const {
        return uint64_t(max.x() - min.x() + 1) * uint64_t(max.y() - min.y() + 1) *
               uint64_t(max.z() - min.z() + 1);
    }
    int channels = 1;
    uint64_t bytes() const { return 48 + 4 * uint64_t(channels) * voxels(); }
};

/// The active index bbox [min, max], or the single voxel 0 for an empty grid
/// (which reads as its background, as nanovdbvolume does).
DenseBox dense_box(const openvdb::CoordBBox &b);

/// Physical memory in bytes (0 if unknown).
uint64_t physical_memory();

/// The largest export allowed: --max-dense-bytes, else half the physical memory
uint64_t dense_limit(const Options &opts);

/// Writes the box of the grid `nano` (float, Fp4, Fp8, Fp16, FpN or Vec3f;
/// Error naming `name` otherwise) as .vol at `path`; its world bbox is that
/// of the voxels' cells through `xform`. One z slab in memory at a time.
void write_dense(const Handle &nano, const std::string &name,
                 const openvdb::math::Transform &xform, const DenseBox &box,
                 const std::string &path);

} // namespace vdb2nvdb
