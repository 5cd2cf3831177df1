// nanovdb_loader/build.h -- a NanoVDB grid made in memory from values the
// caller holds: a dense box (what gridvolume's `data` tensor or VolumeGrid
// holds), or voxels given one by one with their coordinates.
//
// The grid is built by NanoVDB's own GridBuilder (nanovdb/util/GridBuilder.h,
// from the libnanovdb-dev package): float for one channel, Vec3f for three.
// Voxels whose every channel lies within `threshold` of the background are
// left out (inactive, reading the background); the others are active voxels
// of the grid. With the default threshold 0 only exact background values are
// left out, so the grid reads exactly as the dense values everywhere in their
// box. The bytes that come out are an ordinary grid buffer, decoded and
// validated like a file's (load.h: decode_grid_bytes).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// A dense box of values at index coordinates [0, size) per axis: value c
/// of voxel (x, y, z) is values[((z * size[1] + y) * size[0] + x) * channels
/// + c], the layout of gridvolume's tensors and .vol files
struct DenseValues {
    const float *values = nullptr;
    uint32_t size[3] = { 0, 0, 0 };
    uint32_t channels = 1; ///< 1 or 3
};

/// Voxels one by one: coords[3 i .. 3 i + 2] is voxel i's index coordinate,
/// values[channels i ..] its value (a voxel given twice keeps the last value)
struct SparseValues {
    const int32_t *coords = nullptr;
    const float *values = nullptr;
    uint64_t count = 0;
    uint32_t channels = 1; ///< 1 or 3
};

struct BuildOptions {
    std::string name = "data";  ///< the grid's name
    float background = 0.f;     ///< the value outside the active voxels (every channel)
    float threshold = 0.f;      ///< |value - background| <= this (every channel): left out
};

/// What a built grid holds, besides its bytes
struct BuiltGrid {
    std::vector<uint8_t> bytes; ///< a NanoVDB grid buffer (one grid)
    uint64_t active = 0;        ///< active voxels
    uint64_t left_out = 0;      ///< voxels within the threshold of the background
};

/// `label` names the source in errors ("nanovdb_loader::Error: \"<label>\": ...")
BuiltGrid build_grid(const std::string &label, const DenseValues &dense,
                     const BuildOptions &options);
BuiltGrid build_grid(const std::string &label, const SparseValues &sparse,
                     const BuildOptions &options);

} // namespace nanovdb_loader
