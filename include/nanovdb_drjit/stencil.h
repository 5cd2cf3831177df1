/*
    nanovdb_drjit/stencil.h -- beyond PNanoVDB: the 2x2x2 trilinear stencil

    A trilinear lookup reads the 8 corners ijk0 + {0,1}^3. Traversing the tree
    8 times (what 8 calls of root_get_value would do) repeats the root search
    and the upper level 8 times although the corners share their lower node
    in 98 % of the cases (a stencil crosses a 128-voxel boundary on an axis
    only when ijk0 & 127 == 127), and their leaf in 67 %. Here the first
    corner is traversed once down to its lower node and leaf; each corner then
    reads from the shared leaf, or from the shared lower node, or -- only
    for lanes whose corner lies in another 128^3 block -- traverses the tree
    itself inside a symbolic conditional (`dr::if_stmt`), which the JIT
    backends skip for every packet of lanes that does not need it.

    Works with every reader of pnanovdb.h and fast_readers.h. Tested against 8
    PNanoVDB traversals per stencil (tests/test_translation.cpp).
*/

#pragma once

#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/traversal.h>

#include <tuple>
#include <type_traits>

#include <drjit/if_stmt.h>

namespace nanovdb_drjit {

/// Where a traversal from the root stops at the lower level: the lower node
/// (if any) and otherwise the value address and level of the tile or
/// background that covers the whole 128^3 block of `ijk`.
template <typename UInt32> struct LowerOrValue {
    UInt32 lower;                  ///< lower node address (valid where has_lower)
    dr::mask_t<UInt32> has_lower;
    UInt32 address, level;         ///< value address/level (valid where !has_lower)
};

/// Traversal root -> upper -> lower, stopping at the lower node (the two
/// steps of traversal.h)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
LowerOrValue<UInt32> root_get_lower(const Buffer &buf, const Root &root,
                                    const Coord<UInt32> &ijk,
                                    const dr::mask_t<UInt32> &active) {
    RootToUpper<UInt32> ru = root_get_upper<GridType>(buf, root, ijk, active);
    UpperToLower<UInt32> ul = upper_get_lower<GridType>(buf, ru.upper, ijk, ru.has_upper);
    AddressAndLevel<UInt32> above = above_lower<GridType>(root, ru, ul);
    return { ul.lower.address, ul.has_lower, above.address, above.level };
}

/// The value addresses and levels of a stencil's 8 corners
template <typename UInt32> struct StencilAddresses {
    dr::Array<UInt32, 8> address, level;
};

/**
 * Value addresses and levels of the 8 corners ijk0 + (i, j, k), i, j, k in
 * {0, 1}, in the order corner = i + 2 j + 4 k (x fastest, as Dr.Jit's
 * texture). Each equals root_get_value_address_and_level(buf, root, ijk0 +
 * (i, j, k)). The levels are what the quantized and half readers need
 * (root_read_float); WithLevel = false leaves them out (float grids).
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, bool WithLevel = true, typename Buffer,
          typename Root, typename UInt32 = decltype(Root::address)>
StencilAddresses<UInt32> root_get_stencil(const Buffer &buf, const Root &root,
                                          const Coord<UInt32> &ijk0,
                                          const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    using Addresses = dr::Array<UInt32, 8>;

    LowerOrValue<UInt32> base = root_get_lower<GridType>(buf, root, ijk0, active);
    LowerHandle<UInt32> lower{ base.lower };
    UInt32 n0 = lower_coord_to_offset(ijk0);
    Mask has_leaf = lower_get_child_mask(buf, lower, n0, base.has_lower);
    LeafHandle<UInt32> leaf = lower_get_child<GridType>(buf, lower, n0, has_leaf);

    // Does +1 along an axis stay in the leaf (8^3) / the lower node's block (128^3)?
    Mask stay_leaf[3], stay_lower[3];
    for (int k = 0; k < 3; ++k) {
        stay_leaf[k]  = (ijk0[k] & 7) != 7;
        stay_lower[k] = (ijk0[k] & 127) != 127;
    }

    Addresses result, levels = dr::zeros<Addresses>();
    Mask far[8], any_far = false;
    for (uint32_t corner = 0; corner < 8; ++corner) {
        uint32_t bit[3] = { corner & 1u, (corner >> 1) & 1u, (corner >> 2) & 1u };
        Coord<UInt32> ijk = coord_add<UInt32>(ijk0, bit[0], bit[1], bit[2]);
        Mask in_leaf = has_leaf, in_lower = active;
        for (int k = 0; k < 3; ++k) {
            if (bit[k]) {
                in_leaf &= stay_leaf[k];
                in_lower &= stay_lower[k];
            }
        }

        // Same leaf as corner 0
        UInt32 address = leaf_get_value_address<GridType>(leaf, ijk);
        // Same lower node, another leaf (or a tile of the lower node)
        Mask via_lower = in_lower & base.has_lower & !in_leaf;
        AddressAndLevel<UInt32> al =
            lower_get_value_address_and_level<GridType>(buf, lower, ijk, via_lower);
        address = dr::select(via_lower, al.address, address);
        // Corner 0 stopped above the lower level: that tile (or the
        // background) covers the whole 128^3 block, this corner included
        Mask above = in_lower & !base.has_lower;
        result[corner] = dr::select(above, base.address, address);
        if constexpr (WithLevel)
            levels[corner] = dr::select(above, base.level,
                                        dr::select(via_lower, al.level, UInt32(LEVEL_LEAF)));

        far[corner] = active & !in_lower;
        any_far |= far[corner];
    }

    // Corners in another 128^3 block: full traversals, in one conditional
    // that the JIT backends skip for every packet of lanes without any
    using State = std::conditional_t<WithLevel, dr::Array<Addresses, 2>, Addresses>;
    auto traverse_far = [buf, root, ijk0](const State &state, const dr::Array<Mask, 8> &far_) {
        State out = state;
        for (uint32_t corner = 1; corner < 8; ++corner) {
            Coord<UInt32> ijk =
                coord_add<UInt32>(ijk0, corner & 1u, (corner >> 1) & 1u, (corner >> 2) & 1u);
            AddressAndLevel<UInt32> al =
                value_address_and_level<GridType>(buf, root, ijk, far_[corner]);
            if constexpr (WithLevel) {
                out[0][corner] = dr::select(far_[corner], al.address, out[0][corner]);
                out[1][corner] = dr::select(far_[corner], al.level, out[1][corner]);
            } else {
                out[corner] = dr::select(far_[corner], al.address, out[corner]);
            }
        }
        return out;
    };
    dr::Array<Mask, 8> far_mask;
    for (uint32_t corner = 0; corner < 8; ++corner)
        far_mask[corner] = far[corner];
    State state;
    if constexpr (WithLevel)
        state = State(result, levels);
    else
        state = result;
    if constexpr (dr::is_jit_v<UInt32>) {
        state = dr::if_stmt(
            std::make_tuple(state, far_mask), any_far, traverse_far,
            [](const State &s, const dr::Array<Mask, 8> &) { return s; },
            "nanovdb_stencil_far_corners");
    } else {
        if (any_far)
            state = traverse_far(state, far_mask);
    }
    if constexpr (WithLevel)
        return { state[0], state[1] };
    else
        return { state, levels };
}

/// The 8 corners' value addresses alone (root_get_stencil without levels)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
dr::Array<UInt32, 8> root_get_stencil_addresses(const Buffer &buf, const Root &root,
                                                const Coord<UInt32> &ijk0,
                                                const dr::mask_t<UInt32> &active) {
    return root_get_stencil<GridType, false>(buf, root, ijk0, active).address;
}

} // namespace nanovdb_drjit
