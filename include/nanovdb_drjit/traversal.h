/*
    nanovdb_drjit/traversal.h -- beyond PNanoVDB: the traversal prefix, root
    -> upper -> lower, in two steps that the fast readers share

    PNanoVDB's pnanovdb_root_get_value_address_and_level (pnanovdb.h, kept
    function for function as the reference) goes down the tree in nested
    calls. Three readers here need to stop, or to choose, part of the way
    down: the trilinear stencil (stencil.h) shares one traversal to the lower
    node among its 8 corners; the majorant walk (majorant_walk.h) decides at
    each level whether to cross a node whole; the value reader below goes to
    the leaf. They all take the same two steps:

      root_get_upper:   the root tile of ijk's 4096^3 block, and its upper
                        node if it has one;
      upper_get_lower:  the entry of ijk in that upper node, and its lower
                        node if it has one.

    Each step reads what PNanoVDB's reads at that level, with the same
    functions (pnanovdb.h), so every reader stays read for read equal to
    PNanoVDB (tests/test_translation.cpp).
*/

#pragma once

#include <nanovdb_drjit/pnanovdb.h>

namespace nanovdb_drjit {

/// Where root_get_upper stops: the root tile (if any) and its upper node
/// (if it has a child)
template <typename UInt32> struct RootToUpper {
    RootTileHandle<UInt32> tile;
    dr::mask_t<UInt32> found;      ///< a root tile covers ijk's block
    UpperHandle<UInt32> upper;
    dr::mask_t<UInt32> has_upper;  ///< ... and it has an upper node
};

/// Step 1: the root tile of ijk and its child
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE RootToUpper<UInt32> root_get_upper(const Buffer &buf, const Root &root,
                                                const Coord<UInt32> &ijk,
                                                const dr::mask_t<UInt32> &active) {
    RootToUpper<UInt32> out;
    out.tile = root_find_tile<GridType>(buf, root, ijk, active);
    out.found = active & (out.tile.address != 0u);
    // PNanoVDB: pnanovdb_root_tile_get_child, pnanovdb_int64_is_zero
    auto [delta, nonzero] = read_int64_as_word_delta(
        buf, UInt32(out.tile.address + to_words(ROOT_TILE_OFF_CHILD)), out.found);
    out.has_upper = out.found & nonzero;
    out.upper = root_get_child(root, delta);
    return out;
}

/// Where upper_get_lower stops: ijk's entry in the upper node, and its lower
/// node (if the entry is a child)
template <typename UInt32> struct UpperToLower {
    UInt32 n;                      ///< the entry (upper_coord_to_offset)
    dr::mask_t<UInt32> has_lower;
    LowerHandle<UInt32> lower;
};

/// Step 2: ijk's entry in `upper` (lanes of `active`) and its child
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename UInt32>
DRJIT_INLINE UpperToLower<UInt32> upper_get_lower(const Buffer &buf,
                                                  const UpperHandle<UInt32> &upper,
                                                  const Coord<UInt32> &ijk,
                                                  const dr::mask_t<UInt32> &active) {
    UpperToLower<UInt32> out;
    out.n = upper_coord_to_offset(ijk);
    out.has_lower = upper_get_child_mask(buf, upper, out.n, active);
    out.lower = upper_get_child<GridType>(buf, upper, out.n, out.has_lower);
    return out;
}

/// The value address and level of a tile or the background above the lower
/// level: what covers ijk's whole 128^3 block when it has no lower node
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE AddressAndLevel<UInt32> above_lower(const Root &root, const RootToUpper<UInt32> &ru,
                                                 const UpperToLower<UInt32> &ul) {
    UInt32 address = dr::select(ru.found, root_tile_get_value_address<GridType>(ru.tile),
                                root_get_background_address<GridType>(root)),
           level   = dr::select(ru.found, UInt32(LEVEL_ROOT_TILE), UInt32(LEVEL_BACKGROUND));
    address = dr::select(ru.has_upper, upper_get_table_address<GridType>(ru.upper, ul.n), address);
    level   = dr::select(ru.has_upper, UInt32(LEVEL_UPPER), level);
    return { address, level };
}

/**
 * The value address and level of ijk through the two steps and the lower
 * node: the same as PNanoVDB's root_get_value_address_and_level (pnanovdb.h),
 * the readers' path (sampler.h)
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE AddressAndLevel<UInt32> value_address_and_level(const Buffer &buf,
                                                             const Root &root,
                                                             const Coord<UInt32> &ijk,
                                                             const dr::mask_t<UInt32> &active) {
    RootToUpper<UInt32> ru = root_get_upper<GridType>(buf, root, ijk, active);
    UpperToLower<UInt32> ul = upper_get_lower<GridType>(buf, ru.upper, ijk, ru.has_upper);
    AddressAndLevel<UInt32> below =
        lower_get_value_address_and_level<GridType>(buf, ul.lower, ijk, ul.has_lower);
    AddressAndLevel<UInt32> above = above_lower<GridType>(root, ru, ul);
    return { dr::select(ul.has_lower, below.address, above.address),
             dr::select(ul.has_lower, below.level, above.level) };
}

} // namespace nanovdb_drjit
