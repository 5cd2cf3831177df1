/*
    nanovdb_drjit/majorant_table.h -- where a grid's per-node majorants live

    Beyond PNanoVDB: majorant tracking walks a ray through the tree one node
    at a time (majorant_walk.h) and needs, for every node and tile it stops
    at, an upper bound of every value a lookup can return at a point of that
    node's region. The loader computes them once per grid
    (src/loader/node_majorants.cpp) into one float array beside the grid; this
    header says where each bound sits in it. Plain C++: the loader and the
    device code both include it.

    The array, in slots of one float:

      [0, leaf_count)                         one per leaf, in leaf array order
      lower_slot + 2 n, lower_slot + 2 n + 1  lower node n: M, R
      upper_slot + 2 n, upper_slot + 2 n + 1  upper node n: M, R
      tile_slot + t                           root tile t, in table order
      background_slot                         the background

    M bounds the node's whole region; R is the node's "ring bound" for its
    tiles: a tile of value v is bounded by max(v, R). A leaf's slot bounds
    its 8^3 voxels. See nanovdb_loader/majorants.h for the exact definitions.

    A slot is found from the node's word address without a search: node
    arrays are contiguous with a fixed stride per level (validation checks
    it), so slot = first slot + (address - array begin) / node words, a
    division by a per-type constant (a multiply-high on the device).
*/

#pragma once

#include <cstdint>

namespace nanovdb_drjit {

/// Where the bounds of a grid's nodes sit in its majorant array
struct MajorantTableLayout {
    uint32_t leaf_begin_word  = 0; ///< word address of the first leaf
    uint32_t lower_begin_word = 0; ///< ... of the first lower node
    uint32_t upper_begin_word = 0; ///< ... of the first upper node
    uint32_t tile_begin_word  = 0; ///< ... of the first root tile
    uint32_t lower_slot = 0, upper_slot = 0, tile_slot = 0, background_slot = 0;
    uint32_t size = 0;             ///< slots in all

    /// The layout for a grid with these node counts and arrays
    static MajorantTableLayout make(const uint64_t node_begin[3],
                                    const uint32_t node_count[3], uint32_t root_word,
                                    uint32_t root_size, uint32_t root_tile_count) {
        MajorantTableLayout t;
        t.leaf_begin_word  = uint32_t(node_begin[0] / 4);
        t.lower_begin_word = uint32_t(node_begin[1] / 4);
        t.upper_begin_word = uint32_t(node_begin[2] / 4);
        t.tile_begin_word  = root_word + root_size / 4;
        t.lower_slot       = node_count[0];
        t.upper_slot       = t.lower_slot + 2 * node_count[1];
        t.tile_slot        = t.upper_slot + 2 * node_count[2];
        t.background_slot  = t.tile_slot + root_tile_count;
        t.size             = t.background_slot + 1;
        return t;
    }
};

} // namespace nanovdb_drjit
