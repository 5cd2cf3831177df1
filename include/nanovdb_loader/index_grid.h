// nanovdb_loader/index_grid.h -- index grids (NanoVDB's OnIndex): a tree
// that maps each active voxel and active tile to a value index, and the
// values it indexes, kept apart from the tree.
//
// Two sources:
//  * a file's OnIndex grid (fVDB, Warp): its values are a blind channel of
//    the grid (take_blind_values);
//  * any scalar grid (float, Half, Fp4/8/16/N), made into an index grid with
//    the same tree and its active values as floats (make_index_grid): the
//    differentiable form of a volume, whose values are one float array that
//    lookups gather from.
//
// The values' order, for a made grid (what `data` exposes in the plugin):
// value index i >= 1 is values[i - 1]; index 0 is the background (not in the
// array). Indices follow the tree in array order: the root tiles (table
// order), then the tiles of the upper nodes, then of the lower nodes (node by
// node, entry by entry), then the active voxels of the leaves (leaf by leaf,
// voxel offset n = (x & 7) << 6 | (y & 7) << 3 | (z & 7) ascending within a
// leaf). A tile gets an index if it is active or holds a value other than
// the background (it covers its region as the grid's tile does); an inactive
// leaf voxel reads the background (a leaf indexes its active voxels only:
// MadeIndexGrid counts those whose value differed). A file's index grid
// keeps its own indices.
#pragma once

#include <nanovdb_loader/validation.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// An index grid's values: index i >= 1 at values[i - 1], index 0 the background
struct IndexGridValues {
    std::vector<float> values; ///< `channels` floats a value, interleaved
    std::array<float, 3> background{}; ///< index 0's value, per channel
    std::string note; ///< where they came from, for the log
    uint32_t channels = 1;     ///< 1, or 3 (a Vec3f grid made an index grid)
};

/// Which blind channel holds the values, and which float of each value
struct BlindSelection {
    std::string channel;    ///< its name; empty: the first channel of floats
    uint32_t component = 0; ///< per-value floats beyond 1 (fVDB's [N, ...] tensors): this one
};

/**
 * The values of the OnIndex grid at `grid` (`bytes` bytes, blind data
 * included) from a blind channel of floats: NanoVDB's (type Float, 4-byte
 * values, one per value index including the background's, or one per index
 * from 1) or fVDB's (`fvdb_jdata...float32`: bytes holding an int64 shape
 * header [ndim, N, d1, ...] and N x d1 x ... floats, row r for index r + 1).
 * Then drops the blind data from the grid: GridData's size becomes the
 * tree's (returned in `tree_bytes`) and its blind channel count 0, so that
 * the backend holds the tree and the values once. Throws Error naming the
 * file and the problem.
 */
IndexGridValues take_blind_values(const std::string &path, uint8_t *grid, uint64_t bytes,
                                  const BlindSelection &selection, uint64_t &tree_bytes);

/// A grid made into an index grid
struct MadeIndexGrid {
    std::vector<uint8_t> bytes;     ///< the OnIndex grid (no blind data)
    IndexGridValues values;         ///< its active values, in the order above
    /// Inactive leaf voxels whose value differs from the background: the
    /// index grid reads the background there
    uint64_t inactive_differing = 0;
};

/// The OnIndex grid with the tree of `grid` (float, Half or quantized, whose
/// values become floats as lookups decode them, or Vec3f, whose values
/// become three floats each) and its active values. Throws Error for index
/// grids and for 2^32 - 1 values or more.
MadeIndexGrid make_index_grid(const ValidatedGrid &grid);

} // namespace nanovdb_loader
