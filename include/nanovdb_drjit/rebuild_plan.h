/*
    nanovdb_drjit/rebuild_plan.h -- what the backend needs to rebuild an
    index grid's majorant table after its values change

    Beyond PNanoVDB. An index grid's tree never changes when an optimizer
    updates its values (params.update()): only the values do. The loader
    (src/loader/rebuild_plan.cpp) reads once, at load, what of the tree the
    table's passes need (node_majorants: which entry is a child and which
    a tile, what lies beside each node); majorant_rebuild.h then computes
    the table from the values on the backend, with no host round trip:
    the same table, bit for bit, as node_majorants computes from the same
    values (tests/test_majorant_walk.cpp). Plain C++: the loader and the
    device code both include it.

    A code names what covers a cell: a node of the level below the
    entry's (>= 0: its index in array order), or a value (-1 - its value
    index; 0 is the background).
*/

#pragma once

#include "majorant_table.h"

#include <cstdint>
#include <vector>

namespace nanovdb_drjit {

/// A value index as a code, and back
constexpr int32_t value_code(uint32_t value_index) { return -1 - int32_t(value_index); }
constexpr uint32_t code_value(int32_t code) { return uint32_t(-1 - code); }

/// The index of direction (dx, dy, dz) in [-1, 1]^3 among 27 (13: none)
constexpr uint32_t direction_index(int dx, int dy, int dz) {
    return uint32_t((dx + 1) * 9 + (dy + 1) * 3 + (dz + 1));
}

/// fn(dx, dy, dz) for the 26 directions around a cell, in direction_index order
template <typename Fn> void for_each_direction(Fn &&fn) {
    for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz)
                if (dx || dy || dz)
                    fn(dx, dy, dz);
}

/// Which layer of a cell a neighbour in direction d touches, per axis: 0 all
/// of it, 1 its low end, 2 its high end; as 9 sx + 3 sy + sz (0..26). The
/// neighbour at +x touches the cell's low x end (its own layer: `ours`)
constexpr uint32_t layer_of_direction(int dx, int dy, int dz, bool ours) {
    auto sel = [ours](int d) { return d == 0 ? 0u : ((d > 0) != ours) ? 1u : 2u; };
    return 9 * sel(dx) + 3 * sel(dy) + sel(dz);
}

struct MajorantRebuildPlan {
    MajorantTableLayout layout;
    uint32_t ring = 1;            ///< the leaves' layer thickness, voxels (1..8)
    uint32_t leaf_count = 0, lower_count = 0, upper_count = 0;
    uint32_t leaf_words = 0;      ///< words per (OnIndex) leaf
    uint32_t background_index = 0; ///< the background's value index
    /// Per lower node, its 16^3 entries: a leaf or a value; per upper node,
    /// its 32^3: a lower node or a value
    std::vector<int32_t> lower_entries, upper_entries;
    /// The entries (node * entries + entry, ascending) whose ring is not
    /// the 3^3 tile values around them: children, entries on the node's
    /// faces, tiles beside a child (majorant_rebuild.h, rings())
    std::vector<uint32_t> lower_slow, upper_slow;
    /// Per lower (upper) node, 27 codes: what covers the node-sized cell in
    /// each direction (direction_index; 13 is the node itself): a node of
    /// the same level or a value
    std::vector<int32_t> lower_around, upper_around;
    /// The root tiles lookups reach: their table index, an upper node or a
    /// value, and 27 codes around each (upper nodes or values)
    std::vector<uint32_t> tile_index;
    std::vector<int32_t> tile_codes, tile_around;
    /// The background's slot: the layers (layer_of_direction, ours) of
    /// reached tiles that touch space no tile covers, and their tile's code
    std::vector<int32_t> background_codes;
    std::vector<uint32_t> background_layers;
    /// For the mean bound (mean_bound() of the loader): the first voxel
    /// (x, y, z) of each lower and upper node and of each reached tile, and
    /// each lower node's upper node
    std::vector<int32_t> lower_origins, upper_origins, tile_origins;
    std::vector<uint32_t> lower_parent;

    bool empty() const { return layout.size == 0; }
};

} // namespace nanovdb_drjit
