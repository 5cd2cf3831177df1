// nanovdb_loader/validation.h -- is this buffer a grid the traversal can trust?
//
// validate_grid() checks a decoded grid buffer so that the PNanoVDB
// traversal (root -> upper -> lower -> leaf) of any coordinate never leaves
// it, and summarises it in the same pass: its header fields (GridSummary) and
// every value a lookup can return (ValueStats). Its result, ValidatedGrid, is
// the only way to say "validated": every later step (value policy, reader
// policy, bounds, upload) takes one, so a grid is validated exactly once.
//
// Values: validation decodes every value once, for ValueStats and each
// leaf's min and max. The later passes read again only these:
//  * sanitize_values() (invalid_values="clamp", for a grid that has invalid
//    values): every value, rewritten where invalid;
//  * max_in_box(): the tiles the box meets and the voxels of the leaves it
//    cuts (whole leaves through their max); max_in_box_per_channel() (Vec3f):
//    every voxel in the box;
//  * node_majorants(): every tile value of the internal nodes and root, and
//    the border voxels of the leaves whose max could raise a neighbour's
//    bound; mean_bound(): the tile values of the nodes the box meets;
//  * the spectral rewrite (spectral.h, Vec3f in spectral variants): every
//    value, read and rewritten as coefficients.
//
// What is required:
//  * magic "NanoVDB0"/"NanoVDB1", major version 32, a supported grid type
//    (layout.h's VALUE_TYPES: float, half, fp4, fp8, fp16, fpn, vec3f),
//    GridData.mGridSize within the buffer;
//  * FpN leaves: a code width of 1 to 16 bits (flags >> 5 at most 4); the
//    leaves, each as long as its width makes it, fill the leaf array;
//  * the grid/tree header, the root with its tile table and the three node
//    arrays inside the grid, 32-byte aligned and disjoint (NanoVDB writes them
//    back to back; overlapping regions would let one node's bytes be read as
//    a node of another level);
//  * every root tile key is one a coordinate has (PNanoVDB's coord_to_key
//    leaves the top bit of each 21-bit field, and bit 63, clear): PNanoVDB
//    never finds a tile with another key, while an index by block would;
//  * every child offset (root tiles, upper and lower tables) lands exactly on
//    a node of the level below, so a child can never be its own parent, the
//    root, or a node of the wrong level, and the traversal's fixed depth
//    allows no loop.
// Every node array is walked a bounded number of times: O(nodes), no
// recursion.
//
// Which values (ValueStats): the background, root tiles without child,
// upper/lower table entries whose child bit is 0, and all 512 values of
// every leaf (active or not) -- every value a lookup can return, plus values
// in nodes that no root tile reaches (a lookup never returns those, but they
// bound max(), so they are counted too). Quantized and half values are
// decoded first (value_codec.h), as lookups decode them; a Vec3f value
// counts as its three floats. Order (for "first"): background,
// root tiles in table order, upper nodes, lower nodes, leaves, each in array
// order, entries in table order: the order of the bytes in a NanoVDB-written
// buffer.
#pragma once

#include <nanovdb_loader/container.h>

#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// The grid's header fields, as validation read them
struct GridSummary {
    uint32_t grid_type = 0;
    uint32_t grid_class = 0;
    std::string name;
    uint32_t root_word = 0;                ///< byte offset of the root node / 4
    uint32_t root_tile_count = 0;
    int32_t  bbox_min[3] = {}, bbox_max[3] = {}; ///< root's active index bbox, inclusive
    bool     empty = false;                ///< bbox_min > bbox_max on some axis
    float    background = 0.f;
    double   map_mat[9] = {}, map_inv[9] = {}, map_vec[3] = {}; ///< index -> world, row-major
    double   voxel_size[3] = {};
    uint32_t node_count[3] = {};           ///< leaf, lower, upper
    uint64_t node_begin[3] = {};           ///< byte offset of each node array (leaf, lower, upper)
    uint64_t node_end[3] = {};             ///< ... and of its end (FpN leaves differ in size)
    uint64_t active_voxel_count = 0;
};

/**
 * The values of an index grid (OnIndex): value index i >= 1 reads
 * values[i - 1] (Vec3f values, channels 3: the floats values[3 (i - 1) ..
 * 3 (i - 1) + 2]), index 0 the background. They live
 * outside the tree (a blind channel of the file, or an array the caller
 * built): the caller owns them, and they must outlive the ValidatedGrid.
 * The value policy may rewrite them (sanitize_values).
 */
struct IndexValues {
    float *values = nullptr;
    uint64_t count = 0;      ///< values (indices 1 .. count), of `channels` floats
    std::array<float, 3> background{}; ///< index 0's value, per channel
    uint32_t channels = 1;   ///< 1, or 3 (Vec3f values, interleaved)
};

/// Every value a lookup can return (see "Which values" above), summarised
struct ValueStats {
    static constexpr uint64_t NONE = std::numeric_limits<uint64_t>::max();

    /// min / max over every value but NaN (+-Inf included); NaN if every
    /// value is NaN. `max` is what the medium's majorant is built from.
    float min = 0.f, max = 0.f;
    /// min / max over the finite values (+Inf / -Inf if there are none)
    float finite_min = std::numeric_limits<float>::infinity();
    float finite_max = -std::numeric_limits<float>::infinity();
    uint64_t value_count = 0;
    uint64_t nan_count = 0;      ///< NaN (any payload, either sign)
    uint64_t posinf_count = 0;   ///< +Inf
    uint64_t neginf_count = 0;   ///< -Inf
    uint64_t negative_count = 0; ///< finite and < 0 (-0.0 is not negative)
    /// Where the first NaN, infinite and negative value sit, in the order
    /// above; NONE if there is none. A byte offset in the buffer for values
    /// outside leaves; leaf_value_key(leaf index, n) for leaf values (a
    /// quantized value has no byte of its own). values.h's locate_value()
    /// turns either into a voxel.
    uint64_t first_nan = NONE, first_inf = NONE, first_negative = NONE;

    static constexpr uint64_t LEAF_VALUE = uint64_t(1) << 63;
    static uint64_t leaf_value_key(uint64_t leaf, uint32_t n) {
        return LEAF_VALUE | (leaf << 9) | n;
    }

    uint64_t inf_count() const { return posinf_count + neginf_count; }
    bool all_finite() const { return nan_count == 0 && inf_count() == 0; }
};

/**
 * A grid buffer that validate_grid() accepted. It does not own the
 * bytes: it is a view of the caller's buffer, valid while that buffer lives,
 * and the values may change only through sanitize_values() (values.h),
 * which keeps the statistics true, and, last, through the spectral rewrite
 * (spectral.h), after which the grid holds coefficients and the statistics
 * still describe its colours.
 */
class ValidatedGrid {
public:
    const std::string &path() const { return m_path; }
    const uint8_t *data() const { return m_data; }
    const uint32_t *words() const { return reinterpret_cast<const uint32_t *>(m_data); }
    /// The buffer's bytes (the grid may be followed by more grids in it)
    uint64_t bytes() const { return m_bytes; }
    const GridSummary &summary() const { return m_summary; }
    const ValueStats &values() const { return m_values; }
    /// The largest value of each leaf (NaN skipped; -Inf if all its values
    /// are NaN), in leaf array order: what majorants are built from
    const std::vector<float> &leaf_max() const { return m_leaf_max; }
    /// The smallest value of each leaf (NaN skipped; +Inf if all its values
    /// are NaN), in leaf array order: what lets majorant tracking see that a
    /// node holds one value and cross it whole
    const std::vector<float> &leaf_min() const { return m_leaf_min; }

    /// Byte offset of leaf i (leaf array order)
    uint64_t leaf_byte(uint64_t i) const {
        return m_leaf_offsets.empty() ? m_summary.node_begin[0] + i * m_leaf_size
                                      : m_leaf_offsets[size_t(i)];
    }
    /// Index of the leaf whose bytes contain byte offset `byte` (inside the
    /// leaf array)
    uint64_t leaf_containing(uint64_t byte) const;

    /// An index grid's values (count 0 for other grids)
    const IndexValues &index_values() const { return m_index; }
    bool is_index_grid() const { return m_index_grid; }

    /// The spectral rewrite (spectral.h) has turned its colours into
    /// coefficients: values(), leaf_min() and leaf_max() describe the colours
    bool holds_coefficients() const { return m_coefficients; }

private:
    friend ValidatedGrid validate_grid(const std::string &, void *, uint64_t, IndexValues);
    friend ValidatedGrid validate_grid(const std::string &, const void *, uint64_t, IndexValues);
    friend struct ValueRewriter;
    ValidatedGrid() = default;

    std::string m_path;
    uint8_t *m_data = nullptr;
    bool m_writable = false;   ///< validated from a mutable buffer (sanitize_values may write)
    bool m_coefficients = false; ///< rewritten as spectral coefficients
    uint64_t m_bytes = 0;
    GridSummary m_summary;
    ValueStats m_values;
    std::vector<float> m_leaf_min, m_leaf_max;
    uint64_t m_leaf_size = 0;             ///< fixed leaf size (0: FpN)
    std::vector<uint64_t> m_leaf_offsets; ///< FpN only: each leaf's byte offset
    IndexValues m_index;                  ///< index grids only
    bool m_index_grid = false;
};

/// Validates a grid buffer (its first grid, when it holds several) and
/// summarises it; throws Error, naming `path` and the problem. `data` must be
/// 4-byte aligned (the traversal reads 32-bit words). An index grid (OnIndex)
/// needs its values: every index it holds must have one (index <= count);
/// each leaf's prefix sums must match its mask, as the device trusts them.
ValidatedGrid validate_grid(const std::string &path, void *data, uint64_t bytes,
                            IndexValues index = {});

/// The same for a read-only buffer: sanitize_values() refuses the result.
ValidatedGrid validate_grid(const std::string &path, const void *data, uint64_t bytes,
                            IndexValues index = {});

} // namespace nanovdb_loader
