/*
    nanovdb_drjit/pnanovdb.h -- Dr.Jit translation of PNanoVDB's read path

    This header mirrors, function for function, the part of PNanoVDB
    (nanovdb/PNanoVDB.h, NanoVDB 32.4, Copyright Contributors to the OpenVDB
    Project, SPDX-License-Identifier: MPL-2.0) that reading float values needs:
    grid -> tree -> root -> upper -> lower -> leaf. It contains no PNanoVDB
    code: it is a re-implementation in Dr.Jit, written so that a reviewer can
    read both side by side. Each function carries the name of its PNanoVDB
    counterpart in a comment.

    One templated code path serves every backend. The template parameter is the
    32-bit unsigned integer type:

      - `uint32_t`                   -> plain scalar code (Mitsuba scalar_*),
      - `dr::LLVMArray<uint32_t>`    -> vectorized CPU kernels (llvm_ad_*),
      - `dr::CUDAArray<uint32_t>`    -> GPU kernels (cuda_ad_*),
      (and the DiffArray wrappers of the last two that Mitsuba uses).

    Branches on lane data are masks and `dr::select`, the root tile search is a
    `dr::while_loop` (a symbolic loop on JIT backends, a C++ loop on scalars).

    Differences from PNanoVDB, on purpose:

      - Addresses are offsets in 32-bit *words* (bytes / 4), not in bytes.
        Every NanoVDB node is 32-byte aligned, so no precision is lost, and a
        32-bit word offset covers 16 GiB; PNanoVDB's 32-bit byte addresses stop
        at 4 GiB (the prior art's crash on large files). Buffers of 16 GiB or
        more are rejected by the loader (io.h).
      - The 64-bit child offsets stored in the tree (int64, bytes, relative to
        the parent node) are turned into 32-bit word deltas with wrap-around
        arithmetic: (lo >> 2) | (hi << 30). Adding a wrapped delta to a word
        address modulo 2^32 gives the right address whenever the result lies
        in the (validated) buffer, for positive and negative offsets alike.
      - Every read takes an `active` mask, and every gather is masked: an
        inactive lane never touches memory, whatever garbage its address holds.
        A masked read returns 0.
      - Both sides of each branch are evaluated with masks instead of early
        returns (the usual SIMT translation); results are merged with
        `dr::select` in the order PNanoVDB's `if` statements imply.

    Buffer argument (`buf`): either a JIT array of UInt32 (gathered with
    dr::gather) or, for the scalar path, a `const uint32_t *` (read directly
    when active). The loader (io.h) has validated every node offset, so reads
    of active lanes stay inside the buffer.

    Only the float grid type (PNANOVDB_GRID_TYPE_FLOAT) is instantiated; the
    per-type constant table below keeps PNanoVDB's layout so that other value
    types can be added as further rows.
*/

#pragma once

#include <algorithm>
#include <climits>
#include <cstdint>
#include <tuple>
#include <vector>
#include <type_traits>

#include <drjit/array.h>
#include <drjit/if_stmt.h>
#include <drjit/while_loop.h>

namespace nanovdb_drjit {

namespace dr = drjit;

// ---------------------------------------------------------------------------
//  Constants (byte offsets, as in PNanoVDB)
// ---------------------------------------------------------------------------

// PNanoVDB: PNANOVDB_GRID_TYPE_FLOAT
static constexpr uint32_t GRID_TYPE_FLOAT = 1u;

// PNanoVDB: value levels returned by *_get_value_address_and_level
static constexpr uint32_t LEVEL_LEAF       = 0u;
static constexpr uint32_t LEVEL_LOWER      = 1u;
static constexpr uint32_t LEVEL_UPPER      = 2u;
static constexpr uint32_t LEVEL_ROOT_TILE  = 3u;
static constexpr uint32_t LEVEL_BACKGROUND = 4u;

// PNanoVDB: PNANOVDB_GRID_SIZE, PNANOVDB_TREE_OFF_NODE_OFFSET_ROOT, ...
static constexpr uint32_t GRID_SIZE                  = 672u;
static constexpr uint32_t TREE_SIZE                  = 64u;
static constexpr uint32_t TREE_OFF_NODE_OFFSET_ROOT  = 24u;
static constexpr uint32_t ROOT_OFF_BBOX_MIN          = 0u;
static constexpr uint32_t ROOT_OFF_BBOX_MAX          = 12u;
static constexpr uint32_t ROOT_OFF_TABLE_SIZE        = 24u;
static constexpr uint32_t ROOT_TILE_OFF_KEY          = 0u;
static constexpr uint32_t ROOT_TILE_OFF_CHILD        = 8u;
static constexpr uint32_t ROOT_TILE_OFF_STATE        = 16u;
static constexpr uint32_t UPPER_OFF_VALUE_MASK       = 32u;
static constexpr uint32_t UPPER_OFF_CHILD_MASK       = 4128u;
static constexpr uint32_t LOWER_OFF_VALUE_MASK       = 32u;
static constexpr uint32_t LOWER_OFF_CHILD_MASK       = 544u;
static constexpr uint32_t LEAF_OFF_VALUE_MASK        = 16u;

/// PNanoVDB: pnanovdb_grid_type_constants_t (one row per value type)
struct GridTypeConstants {
    uint32_t root_off_background, root_off_min, root_off_max, root_off_ave,
             root_off_stddev, root_size, value_stride_bits, table_stride,
             root_tile_off_value, root_tile_size, upper_off_min, upper_off_max,
             upper_off_ave, upper_off_stddev, upper_off_table, upper_size,
             lower_off_min, lower_off_max, lower_off_ave, lower_off_stddev,
             lower_off_table, lower_size, leaf_off_min, leaf_off_max,
             leaf_off_ave, leaf_off_stddev, leaf_off_table, leaf_size;
};

/// PNanoVDB: pnanovdb_grid_type_constants[PNANOVDB_GRID_TYPE_FLOAT]
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FLOAT = {
    28, 32, 36, 40, 44, 64, 32, 8, 20, 32,
    8224, 8228, 8232, 8236, 8256, 270400,
    1056, 1060, 1064, 1068, 1088, 33856,
    80, 84, 88, 92, 96, 2144
};

template <uint32_t GridType> struct grid_type_constants;
template <> struct grid_type_constants<GRID_TYPE_FLOAT> {
    static constexpr const GridTypeConstants &value = GRID_TYPE_CONSTANTS_FLOAT;
};

/// Byte offset -> word offset (all offsets used here are multiples of 4)
constexpr uint32_t words(uint32_t bytes) { return bytes >> 2; }

// ---------------------------------------------------------------------------
//  Handles (PNanoVDB: pnanovdb_*_handle_t). `address` is a word offset.
// ---------------------------------------------------------------------------

template <typename UInt32> struct GridHandle     { UInt32 address; };
template <typename UInt32> struct TreeHandle     { UInt32 address; };
template <typename UInt32> struct RootHandle     { UInt32 address; };
template <typename UInt32> struct RootTileHandle { UInt32 address; };
template <typename UInt32> struct UpperHandle    { UInt32 address; };
template <typename UInt32> struct LowerHandle    { UInt32 address; };
template <typename UInt32> struct LeafHandle     { UInt32 address; };

/// PNanoVDB: pnanovdb_coord_t
template <typename UInt32>
using Coord = dr::Array<dr::int32_array_t<UInt32>, 3>;

/// ijk + (dx, dy, dz) with int32 wrap-around on every backend (JIT integer
/// arithmetic wraps; plain C++ int32 overflow would be undefined behaviour)
template <typename UInt32>
DRJIT_INLINE Coord<UInt32> coord_add(const Coord<UInt32> &ijk, uint32_t dx, uint32_t dy,
                                     uint32_t dz) {
    using Int32 = dr::int32_array_t<UInt32>;
    auto add = [](const Int32 &v, uint32_t d) {
        return dr::reinterpret_array<Int32>(UInt32(dr::reinterpret_array<UInt32>(v) + d));
    };
    return { add(ijk.x(), dx), add(ijk.y(), dy), add(ijk.z(), dz) };
}

/// A value address together with its level (see LEVEL_*)
template <typename UInt32> struct AddressAndLevel {
    UInt32 address;
    UInt32 level;
};

// ---------------------------------------------------------------------------
//  Buffer reads (PNanoVDB: pnanovdb_read_uint32, pnanovdb_read_int64, ...)
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_read_uint32. Masked: inactive lanes read nothing, get 0.
template <typename UInt32, typename Buffer>
DRJIT_INLINE UInt32 read_uint32(const Buffer &buf, const UInt32 &address,
                                const dr::mask_t<UInt32> &active) {
    if constexpr (std::is_pointer_v<Buffer>) {
        static_assert(!dr::is_array_v<UInt32>,
                      "a raw pointer buffer is for the scalar path only");
        return active ? buf[address] : 0u;
    } else {
        return dr::gather<UInt32>(buf, address, active);
    }
}

/// PNanoVDB: pnanovdb_read_float
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::float32_array_t<UInt32>
read_float(const Buffer &buf, const UInt32 &address,
           const dr::mask_t<UInt32> &active) {
    return dr::reinterpret_array<dr::float32_array_t<UInt32>>(
        read_uint32(buf, address, active));
}

/**
 * PNanoVDB: pnanovdb_read_int64 followed by pnanovdb_address_offset64.
 *
 * Reads an int64 byte offset and returns it as a 32-bit word delta (wrapping),
 * together with a mask telling whether the offset was non-zero (PNanoVDB:
 * !pnanovdb_int64_is_zero). See the header comment for why wrapping is exact.
 */
template <typename UInt32, typename Buffer>
DRJIT_INLINE std::pair<UInt32, dr::mask_t<UInt32>>
read_int64_as_word_delta(const Buffer &buf, const UInt32 &address,
                         const dr::mask_t<UInt32> &active) {
    UInt32 lo = read_uint32(buf, address, active),
           hi = read_uint32(buf, UInt32(address + 1u), active);
    return { (lo >> 2) | (hi << 30), (lo | hi) != 0u };
}

/**
 * Beyond PNanoVDB: a buffer whose child offsets are all known to be
 * non-negative and below 4 GiB, so that only their low word needs reading
 * (one gather instead of two per level). The plugin uses it for grids under
 * 4 GiB whose node arrays are stored in NanoVDB's canonical order (root, upper
 * nodes, lower nodes, leaves), where every child lies after its parent.
 */
template <typename Buffer> struct CompactOffsets {
    Buffer buf;
};

/// PNanoVDB: pnanovdb_read_uint32, on a CompactOffsets buffer
template <typename UInt32, typename Buffer>
DRJIT_INLINE UInt32 read_uint32(const CompactOffsets<Buffer> &buf, const UInt32 &address,
                                const dr::mask_t<UInt32> &active) {
    return read_uint32(buf.buf, address, active);
}

/// read_int64_as_word_delta, on a CompactOffsets buffer: the low word only
template <typename UInt32, typename Buffer>
DRJIT_INLINE std::pair<UInt32, dr::mask_t<UInt32>>
read_int64_as_word_delta(const CompactOffsets<Buffer> &buf, const UInt32 &address,
                         const dr::mask_t<UInt32> &active) {
    UInt32 lo = read_uint32(buf.buf, address, active);
    return { lo >> 2, lo != 0u };
}

// ---------------------------------------------------------------------------
//  Grid and tree
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_grid_get_tree
template <typename UInt32>
DRJIT_INLINE TreeHandle<UInt32> grid_get_tree(const GridHandle<UInt32> &grid) {
    return { UInt32(grid.address + words(GRID_SIZE)) };
}

/// PNanoVDB: pnanovdb_tree_get_root (reads tree.node_offset_root)
template <typename UInt32, typename Buffer>
DRJIT_INLINE RootHandle<UInt32>
tree_get_root(const Buffer &buf, const TreeHandle<UInt32> &tree,
              const dr::mask_t<UInt32> &active = true) {
    UInt32 delta = read_int64_as_word_delta(
        buf, UInt32(tree.address + words(TREE_OFF_NODE_OFFSET_ROOT)), active).first;
    return { UInt32(tree.address + delta) };
}

// ---------------------------------------------------------------------------
//  Root
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_coord_to_key (the 32-bit, non-native-64 variant):
/// returns the 64-bit key as its (low, high) 32-bit words.
template <typename Int32, typename UInt32 = dr::uint32_array_t<Int32>>
DRJIT_INLINE std::pair<UInt32, UInt32> coord_to_key(const dr::Array<Int32, 3> &ijk) {
    UInt32 iu = dr::reinterpret_array<UInt32>(ijk.x()) >> 12,
           ju = dr::reinterpret_array<UInt32>(ijk.y()) >> 12,
           ku = dr::reinterpret_array<UInt32>(ijk.z()) >> 12;
    UInt32 key_x = ku | (ju << 21),
           key_y = (iu << 10) | (ju >> 11);
    return { key_x, key_y };
}

/// PNanoVDB: pnanovdb_root_get_tile_count
template <typename UInt32, typename Buffer>
DRJIT_INLINE UInt32 root_get_tile_count(const Buffer &buf,
                                        const RootHandle<UInt32> &root,
                                        const dr::mask_t<UInt32> &active) {
    return read_uint32(buf, UInt32(root.address + words(ROOT_OFF_TABLE_SIZE)), active);
}

/// PNanoVDB: pnanovdb_root_get_tile_zero
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE RootTileHandle<UInt32> root_get_tile_zero(const RootHandle<UInt32> &root) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return { UInt32(root.address + words(c.root_size)) };
}

/// PNanoVDB: pnanovdb_root_get_tile
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE RootTileHandle<UInt32> root_get_tile(const RootHandle<UInt32> &root,
                                                  const UInt32 &n) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return { UInt32(root.address + words(c.root_size) + n * words(c.root_tile_size)) };
}

/// PNanoVDB: pnanovdb_root_get_background_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE UInt32 root_get_background_address(const Root &root) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return UInt32(root.address + words(c.root_off_background));
}

/// PNanoVDB: pnanovdb_root_tile_get_value_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 root_tile_get_value_address(const RootTileHandle<UInt32> &tile) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return UInt32(tile.address + words(c.root_tile_off_value));
}

/**
 * PNanoVDB: pnanovdb_root_find_tile
 *
 * Linear search of the root table for the tile whose key matches `ijk`, as in
 * PNanoVDB. Returns the null address (0) where no tile matches: the grid
 * header occupies address 0, so no tile can live there (PNanoVDB relies on
 * the same fact). The tile count is read from the buffer, so the kernel does
 * not depend on the file.
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
RootTileHandle<UInt32> root_find_tile(const Buffer &buf,
                                      const RootHandle<UInt32> &root,
                                      const Coord<UInt32> &ijk,
                                      const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;

    // Inactive lanes get a tile count of zero and never enter the loop
    UInt32 tile_count = root_get_tile_count(buf, root, active);
    auto [key_x, key_y] = coord_to_key(ijk);

    UInt32 i = 0u,
           tile = root_get_tile_zero<GridType>(root).address,
           found = 0u;

    std::tie(i, tile, found) = dr::while_loop(
        std::make_tuple(i, tile, found),
        [tile_count](const UInt32 &i, const UInt32 &, const UInt32 &found) {
            return Mask((i < tile_count) & (found == 0u));
        },
        [buf, key_x = key_x, key_y = key_y, tile_count](UInt32 &i, UInt32 &tile,
                                                        UInt32 &found) {
            Mask in_loop = Mask((i < tile_count) & (found == 0u));
            // PNanoVDB: pnanovdb_root_tile_get_key
            UInt32 kx = read_uint32(buf, UInt32(tile + words(ROOT_TILE_OFF_KEY)), in_loop),
                   ky = read_uint32(buf, UInt32(tile + words(ROOT_TILE_OFF_KEY) + 1u), in_loop);
            Mask match = in_loop & (kx == key_x) & (ky == key_y);
            found = dr::select(match, tile, found);
            tile += words(c.root_tile_size);
            i += 1u;
        },
        "nanovdb_root_find_tile");

    return { found };
}

/// PNanoVDB: pnanovdb_root_get_child (child offset is relative to the root)
template <typename Root, typename UInt32 = decltype(Root::address)>
DRJIT_INLINE UpperHandle<UInt32> root_get_child(const Root &root,
                                                const UInt32 &child_delta) {
    return { UInt32(root.address + child_delta) };
}

/**
 * Beyond PNanoVDB: a root handle with an O(1) tile index.
 *
 * `table` holds, for every 4096^3 block of the box of blocks spanned by the
 * root's tiles, the word address of that block's root tile (0: no tile, i.e.
 * background). A block is ijk >> 12 (arithmetic shift), the same grouping as
 * coord_to_key. It replaces PNanoVDB's linear search of the root table (a
 * loop with two gathers per tile) by one gather. The plugin builds it on the
 * host when it is small (see build_root_index); `Table` is a JIT array or, on
 * the scalar path, a `const uint32_t *`.
 */
template <typename UInt32, typename Table> struct IndexedRootHandle {
    UInt32 address;                     ///< the root node, as in RootHandle
    Table table;                        ///< tile word addresses, x-major
    Coord<UInt32> block_min;            ///< smallest block coordinate
    Coord<UInt32> block_dims;           ///< extent of the box of blocks
};

/// PNanoVDB: pnanovdb_root_find_tile, by table lookup
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Table,
          typename Buffer>
DRJIT_INLINE RootTileHandle<UInt32>
root_find_tile(const Buffer & /* buf */, const IndexedRootHandle<UInt32, Table> &root,
               const Coord<UInt32> &ijk, const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    Coord<UInt32> rel = (ijk >> 12) - root.block_min;
    Mask inside = active;
    for (int k = 0; k < 3; ++k)
        inside &= (rel[k] >= 0) & (rel[k] < root.block_dims[k]);
    UInt32 index = dr::reinterpret_array<UInt32>(
        (rel.x() * root.block_dims.y() + rel.y()) * root.block_dims.z() + rel.z());
    return { read_uint32(root.table, index, inside) };
}

// ---------------------------------------------------------------------------
//  Upper internal node (32^3 children of 128^3 voxels)
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_upper_coord_to_offset
template <typename Int32, typename UInt32 = dr::uint32_array_t<Int32>>
DRJIT_INLINE UInt32 upper_coord_to_offset(const dr::Array<Int32, 3> &ijk) {
    UInt32 i = dr::reinterpret_array<UInt32>(ijk.x()),
           j = dr::reinterpret_array<UInt32>(ijk.y()),
           k = dr::reinterpret_array<UInt32>(ijk.z());
    return (((i & 4095u) >> 7) << 10) | (((j & 4095u) >> 7) << 5) |
           ((k & 4095u) >> 7);
}

/// PNanoVDB: pnanovdb_upper_get_child_mask
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::mask_t<UInt32>
upper_get_child_mask(const Buffer &buf, const UpperHandle<UInt32> &upper,
                     const UInt32 &bit_index, const dr::mask_t<UInt32> &active) {
    UInt32 value = read_uint32(
        buf, UInt32(upper.address + words(UPPER_OFF_CHILD_MASK) + (bit_index >> 5)),
        active);
    return active & (((value >> (bit_index & 31u)) & 1u) != 0u);
}

/// PNanoVDB: pnanovdb_upper_get_table_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 upper_get_table_address(const UpperHandle<UInt32> &node,
                                            const UInt32 &n) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return UInt32(node.address + words(c.upper_off_table) + n * words(c.table_stride));
}

/// PNanoVDB: pnanovdb_upper_get_child (child offset is relative to the node)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
DRJIT_INLINE LowerHandle<UInt32>
upper_get_child(const Buffer &buf, const UpperHandle<UInt32> &upper,
                const UInt32 &n, const dr::mask_t<UInt32> &active) {
    UInt32 delta = read_int64_as_word_delta(
        buf, upper_get_table_address<GridType>(upper, n), active).first;
    return { UInt32(upper.address + delta) };
}

// ---------------------------------------------------------------------------
//  Lower internal node (16^3 children of 8^3 voxels)
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_lower_coord_to_offset
template <typename Int32, typename UInt32 = dr::uint32_array_t<Int32>>
DRJIT_INLINE UInt32 lower_coord_to_offset(const dr::Array<Int32, 3> &ijk) {
    UInt32 i = dr::reinterpret_array<UInt32>(ijk.x()),
           j = dr::reinterpret_array<UInt32>(ijk.y()),
           k = dr::reinterpret_array<UInt32>(ijk.z());
    return (((i & 127u) >> 3) << 8) | (((j & 127u) >> 3) << 4) |
           ((k & 127u) >> 3);
}

/// PNanoVDB: pnanovdb_lower_get_child_mask
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::mask_t<UInt32>
lower_get_child_mask(const Buffer &buf, const LowerHandle<UInt32> &lower,
                     const UInt32 &bit_index, const dr::mask_t<UInt32> &active) {
    UInt32 value = read_uint32(
        buf, UInt32(lower.address + words(LOWER_OFF_CHILD_MASK) + (bit_index >> 5)),
        active);
    return active & (((value >> (bit_index & 31u)) & 1u) != 0u);
}

/// PNanoVDB: pnanovdb_lower_get_table_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 lower_get_table_address(const LowerHandle<UInt32> &node,
                                            const UInt32 &n) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    return UInt32(node.address + words(c.lower_off_table) + n * words(c.table_stride));
}

/// PNanoVDB: pnanovdb_lower_get_child
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
DRJIT_INLINE LeafHandle<UInt32>
lower_get_child(const Buffer &buf, const LowerHandle<UInt32> &lower,
                const UInt32 &n, const dr::mask_t<UInt32> &active) {
    UInt32 delta = read_int64_as_word_delta(
        buf, lower_get_table_address<GridType>(lower, n), active).first;
    return { UInt32(lower.address + delta) };
}

// ---------------------------------------------------------------------------
//  Leaf node (8^3 voxels)
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_leaf_coord_to_offset
template <typename Int32, typename UInt32 = dr::uint32_array_t<Int32>>
DRJIT_INLINE UInt32 leaf_coord_to_offset(const dr::Array<Int32, 3> &ijk) {
    UInt32 i = dr::reinterpret_array<UInt32>(ijk.x()),
           j = dr::reinterpret_array<UInt32>(ijk.y()),
           k = dr::reinterpret_array<UInt32>(ijk.z());
    return ((i & 7u) << 6) | ((j & 7u) << 3) | (k & 7u);
}

/// PNanoVDB: pnanovdb_leaf_get_table_address (float: 32-bit values)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 leaf_get_table_address(const LeafHandle<UInt32> &node,
                                           const UInt32 &n) {
    constexpr const GridTypeConstants &c = grid_type_constants<GridType>::value;
    static_assert(c.value_stride_bits == 32, "only 32-bit values are translated");
    return UInt32(node.address + words(c.leaf_off_table) + n);
}

/// PNanoVDB: pnanovdb_leaf_get_value_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 leaf_get_value_address(const LeafHandle<UInt32> &leaf,
                                           const Coord<UInt32> &ijk) {
    return leaf_get_table_address<GridType>(leaf, leaf_coord_to_offset(ijk));
}

// ---------------------------------------------------------------------------
//  Traversal: value address and level
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_lower_get_value_address_and_level
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
AddressAndLevel<UInt32>
lower_get_value_address_and_level(const Buffer &buf,
                                  const LowerHandle<UInt32> &lower,
                                  const Coord<UInt32> &ijk,
                                  const dr::mask_t<UInt32> &active) {
    UInt32 n = lower_coord_to_offset(ijk);
    dr::mask_t<UInt32> has_child = lower_get_child_mask(buf, lower, n, active);
    LeafHandle<UInt32> child = lower_get_child<GridType>(buf, lower, n, has_child);
    return {
        dr::select(has_child, leaf_get_value_address<GridType>(child, ijk),
                   lower_get_table_address<GridType>(lower, n)),
        dr::select(has_child, UInt32(LEVEL_LEAF), UInt32(LEVEL_LOWER))
    };
}

/// PNanoVDB: pnanovdb_upper_get_value_address_and_level
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
AddressAndLevel<UInt32>
upper_get_value_address_and_level(const Buffer &buf,
                                  const UpperHandle<UInt32> &upper,
                                  const Coord<UInt32> &ijk,
                                  const dr::mask_t<UInt32> &active) {
    UInt32 n = upper_coord_to_offset(ijk);
    dr::mask_t<UInt32> has_child = upper_get_child_mask(buf, upper, n, active);
    LowerHandle<UInt32> child = upper_get_child<GridType>(buf, upper, n, has_child);
    AddressAndLevel<UInt32> below =
        lower_get_value_address_and_level<GridType>(buf, child, ijk, has_child);
    return {
        dr::select(has_child, below.address, upper_get_table_address<GridType>(upper, n)),
        dr::select(has_child, below.level, UInt32(LEVEL_UPPER))
    };
}

/// PNanoVDB: pnanovdb_root_get_value_address_and_level
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
AddressAndLevel<UInt32>
root_get_value_address_and_level(const Buffer &buf,
                                 const Root &root,
                                 const Coord<UInt32> &ijk,
                                 const dr::mask_t<UInt32> &active = true) {
    using Mask = dr::mask_t<UInt32>;
    RootTileHandle<UInt32> tile = root_find_tile<GridType>(buf, root, ijk, active);
    Mask found = active & (tile.address != 0u);

    // PNanoVDB: pnanovdb_root_tile_get_child, pnanovdb_int64_is_zero
    auto [delta, nonzero] = read_int64_as_word_delta(
        buf, UInt32(tile.address + words(ROOT_TILE_OFF_CHILD)), found);
    Mask has_child = found & nonzero;

    UpperHandle<UInt32> child = root_get_child(root, delta);
    AddressAndLevel<UInt32> below =
        upper_get_value_address_and_level<GridType>(buf, child, ijk, has_child);

    UInt32 address = dr::select(found, root_tile_get_value_address<GridType>(tile),
                                root_get_background_address<GridType>(root)),
           level   = dr::select(found, UInt32(LEVEL_ROOT_TILE), UInt32(LEVEL_BACKGROUND));
    return { dr::select(has_child, below.address, address),
             dr::select(has_child, below.level, level) };
}

/// PNanoVDB: pnanovdb_root_get_value_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE UInt32 root_get_value_address(const Buffer &buf,
                                           const Root &root,
                                           const Coord<UInt32> &ijk,
                                           const dr::mask_t<UInt32> &active = true) {
    return root_get_value_address_and_level<GridType>(buf, root, ijk, active).address;
}

/**
 * The value at `ijk` (PNanoVDB: pnanovdb_root_get_value_address followed by
 * pnanovdb_read_float). Values outside the tree are the background, as in
 * every VDB. Inactive lanes return 0.
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE dr::float32_array_t<UInt32>
root_get_value(const Buffer &buf, const Root &root,
               const Coord<UInt32> &ijk, const dr::mask_t<UInt32> &active = true) {
    return read_float(buf, root_get_value_address<GridType>(buf, root, ijk, active),
                      active);
}

// ---------------------------------------------------------------------------
//  Beyond PNanoVDB: the 2x2x2 trilinear stencil with one shared traversal
//
//  A trilinear lookup reads the 8 corners ijk0 + {0,1}^3. Traversing the tree
//  8 times (what 8 calls of root_get_value would do) repeats the root search
//  and the upper level 8 times although the corners share their lower node
//  in 98 % of the cases (a stencil crosses a 128-voxel boundary on an axis
//  only when ijk0 & 127 == 127), and their leaf in 67 %. Here the first
//  corner is traversed once down to its lower node and leaf; each corner then
//  reads from the shared leaf, or from the shared lower node, or -- only
//  for lanes whose corner lies in another 128^3 block -- traverses the tree
//  itself inside a symbolic conditional (`dr::if_stmt`), which the JIT
//  backends skip for every packet of lanes that does not need it.
//  Tested against 8 PNanoVDB reads per stencil (tests/test_translation.cpp).
// ---------------------------------------------------------------------------

/// Where a traversal from the root stops at the lower level: the lower node
/// (if any) and otherwise the value address and level of the tile or
/// background that covers the whole 128^3 block of `ijk`.
template <typename UInt32> struct LowerOrValue {
    UInt32 lower;                  ///< lower node address (valid where has_lower)
    dr::mask_t<UInt32> has_lower;
    UInt32 address, level;         ///< value address/level (valid where !has_lower)
};

/// Traversal root -> upper -> lower, stopping at the lower node
/// (the first two steps of root_get_value_address_and_level)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
LowerOrValue<UInt32> root_get_lower(const Buffer &buf, const Root &root,
                                    const Coord<UInt32> &ijk,
                                    const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    RootTileHandle<UInt32> tile = root_find_tile<GridType>(buf, root, ijk, active);
    Mask found = active & (tile.address != 0u);
    auto [delta, nonzero] = read_int64_as_word_delta(
        buf, UInt32(tile.address + words(ROOT_TILE_OFF_CHILD)), found);
    Mask has_upper = found & nonzero;
    UpperHandle<UInt32> upper = root_get_child(root, delta);

    UInt32 n = upper_coord_to_offset(ijk);
    Mask has_lower = upper_get_child_mask(buf, upper, n, has_upper);
    LowerHandle<UInt32> lower = upper_get_child<GridType>(buf, upper, n, has_lower);

    UInt32 address = dr::select(found, root_tile_get_value_address<GridType>(tile),
                                root_get_background_address<GridType>(root)),
           level   = dr::select(found, UInt32(LEVEL_ROOT_TILE), UInt32(LEVEL_BACKGROUND));
    address = dr::select(has_upper, upper_get_table_address<GridType>(upper, n), address);
    level   = dr::select(has_upper, UInt32(LEVEL_UPPER), level);
    return { lower.address, has_lower, address, level };
}

/**
 * Value addresses of the 8 corners ijk0 + (i, j, k), i, j, k in {0, 1}, in the
 * order corner = i + 2 j + 4 k (x fastest, as Dr.Jit's texture). Each address
 * equals root_get_value_address(buf, root, ijk0 + (i, j, k)).
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
dr::Array<UInt32, 8> root_get_stencil_addresses(const Buffer &buf, const Root &root,
                                                const Coord<UInt32> &ijk0,
                                                const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;

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

    dr::Array<UInt32, 8> result;
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
        result[corner] = dr::select(in_lower & !base.has_lower, base.address, address);

        far[corner] = active & !in_lower;
        any_far |= far[corner];
    }

    // Corners in another 128^3 block: full traversals, in one conditional
    // that the JIT backends skip for every packet of lanes without any
    auto traverse_far = [buf, root, ijk0](const dr::Array<UInt32, 8> &addresses,
                                          const dr::Array<Mask, 8> &far_) {
        dr::Array<UInt32, 8> out = addresses;
        for (uint32_t corner = 1; corner < 8; ++corner) {
            Coord<UInt32> ijk =
                coord_add<UInt32>(ijk0, corner & 1u, (corner >> 1) & 1u, (corner >> 2) & 1u);
            out[corner] = dr::select(
                far_[corner],
                root_get_value_address<GridType>(buf, root, ijk, far_[corner]),
                out[corner]);
        }
        return out;
    };
    dr::Array<Mask, 8> far_mask;
    for (uint32_t corner = 0; corner < 8; ++corner)
        far_mask[corner] = far[corner];
    if constexpr (dr::is_jit_v<UInt32>) {
        result = dr::if_stmt(
            std::make_tuple(result, far_mask), any_far, traverse_far,
            [](const dr::Array<UInt32, 8> &addresses, const dr::Array<Mask, 8> &) {
                return addresses;
            },
            "nanovdb_stencil_far_corners");
    } else {
        if (any_far)
            result = traverse_far(result, far_mask);
    }
    return result;
}

// ---------------------------------------------------------------------------
//  Host-side helpers for the accelerated readers (plain C++, run once per
//  file on a buffer that io.h has validated)
// ---------------------------------------------------------------------------

namespace host {

inline uint64_t read_u64(const uint32_t *buf, uint64_t word) {
    return uint64_t(buf[word]) | (uint64_t(buf[word + 1]) << 32);
}

/**
 * True if every child offset of the (validated) float grid in `words` is
 * non-negative and below 4 GiB, so that CompactOffsets may read only their
 * low words: the buffer is smaller than 4 GiB and the node arrays are laid
 * out in NanoVDB's canonical order (root, then upper nodes, lower nodes and
 * leaves, each array after the previous one), so every child lies after its
 * parent. NanoVDB's writers always produce this layout.
 */
inline bool has_compact_offsets(const uint32_t *buf, uint64_t bytes) {
    constexpr const GridTypeConstants &c = GRID_TYPE_CONSTANTS_FLOAT;
    if (bytes >= (uint64_t(1) << 32))
        return false;
    const uint64_t tree = words(GRID_SIZE);
    uint64_t leaf_off  = read_u64(buf, tree + 0) / 4,
             lower_off = read_u64(buf, tree + 2) / 4,
             upper_off = read_u64(buf, tree + 4) / 4,
             root_off  = read_u64(buf, tree + 6) / 4;
    uint64_t n_leaf = buf[tree + 8], n_lower = buf[tree + 9], n_upper = buf[tree + 10];
    // End of the previous array (in words, relative to the tree)
    uint64_t end = root_off + 1;
    if (n_upper) {
        if (upper_off < end) return false;
        end = upper_off + n_upper * words(c.upper_size);
    }
    if (n_lower) {
        if (lower_off < end) return false;
        end = lower_off + n_lower * words(c.lower_size);
    }
    if (n_leaf && leaf_off < end)
        return false;
    return true;
}

/// The O(1) root tile index of IndexedRootHandle, built on the host
struct RootIndex {
    std::vector<uint32_t> table;   ///< tile word addresses (0: none), x-major
    int32_t block_min[3] = { 0, 0, 0 };
    int32_t block_dims[3] = { 0, 0, 0 };
};

/**
 * Builds the root tile index of the (validated) float grid whose root node
 * starts at word `root_word`, or returns false if the box of 4096^3 blocks
 * spanned by its tiles would need more than `max_entries` entries (then the
 * linear search of PNanoVDB is used).
 */
inline bool build_root_index(const uint32_t *buf, uint32_t root_word,
                             uint64_t max_entries, RootIndex &index) {
    constexpr const GridTypeConstants &c = GRID_TYPE_CONSTANTS_FLOAT;
    uint32_t tile_count = buf[root_word + words(ROOT_OFF_TABLE_SIZE)];
    auto block = [](uint64_t key, int shift) {
        // 20-bit (ijk >> 12) of coord_to_key, sign-extended
        uint32_t u = uint32_t((key >> shift) & 0x1FFFFFu);
        return int32_t(u << 12) >> 12;
    };
    int64_t lo[3] = { INT64_MAX, INT64_MAX, INT64_MAX },
            hi[3] = { INT64_MIN, INT64_MIN, INT64_MIN };
    for (uint32_t t = 0; t < tile_count; ++t) {
        uint64_t tile = uint64_t(root_word) + words(c.root_size) + uint64_t(t) * words(c.root_tile_size);
        uint64_t key = read_u64(buf, tile);
        int32_t b[3] = { block(key, 42), block(key, 21), block(key, 0) };
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min<int64_t>(lo[k], b[k]);
            hi[k] = std::max<int64_t>(hi[k], b[k]);
        }
    }
    uint64_t entries = 1;
    if (tile_count == 0) {
        for (int k = 0; k < 3; ++k)
            lo[k] = hi[k] = 0;
    }
    for (int k = 0; k < 3; ++k)
        entries *= uint64_t(hi[k] - lo[k] + 1);
    if (entries > max_entries)
        return false;

    index.table.assign(entries, 0u);
    for (int k = 0; k < 3; ++k) {
        index.block_min[k] = int32_t(lo[k]);
        index.block_dims[k] = tile_count ? int32_t(hi[k] - lo[k] + 1) : 0;
    }
    for (uint32_t t = 0; t < tile_count; ++t) {
        uint64_t tile = uint64_t(root_word) + words(c.root_size) + uint64_t(t) * words(c.root_tile_size);
        uint64_t key = read_u64(buf, tile);
        int64_t b[3] = { block(key, 42), block(key, 21), block(key, 0) };
        uint64_t i = uint64_t(((b[0] - lo[0]) * index.block_dims[1] + (b[1] - lo[1])) *
                                  index.block_dims[2] + (b[2] - lo[2]));
        if (index.table[i] == 0) // like the linear search: the first match wins
            index.table[i] = uint32_t(tile);
    }
    return true;
}

} // namespace host

} // namespace nanovdb_drjit
