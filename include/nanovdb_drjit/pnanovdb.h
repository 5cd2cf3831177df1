/*
    nanovdb_drjit/pnanovdb.h -- Dr.Jit translation of PNanoVDB's read path

    This header mirrors, function for function and section for section, the
    part of PNanoVDB (nanovdb/PNanoVDB.h, NanoVDB 32.4, Copyright Contributors
    to the OpenVDB Project, SPDX-License-Identifier: MPL-2.0) that reading
    float values needs: buffer reads -> grid -> tree -> root -> upper ->
    lower -> leaf -> value address and level. It contains no PNanoVDB code:
    it is a re-implementation in Dr.Jit, written so that a reviewer can read
    both side by side. Each function carries the name of its PNanoVDB
    counterpart in a comment. The byte layout (PNANOVDB_*_OFF_*, the per-type
    constant table) lives in layout.h; what we do beyond PNanoVDB lives in
    fast_readers.h (O(1) root index, 32-bit child offsets) and stencil.h (the
    trilinear stencil), which plug into these functions through overloads.

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
        more are rejected by the loader (src/loader/validation.cpp).
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
    when active). The loader has validated every node offset, so reads of
    active lanes stay inside the buffer.

    The functions take the grid type as a template parameter and read the
    offsets of its row of layout.h, as PNanoVDB's functions take `grid_type`.
    Value reads follow PNanoVDB's per-type readers: float (pnanovdb_read_float),
    Half (pnanovdb_read_half, converted to float here: PNanoVDB's C path
    returns the raw bits), Fp4/Fp8/Fp16/FpN (pnanovdb_root_fp*_read_float: a
    float at tiles, code * quantum + minimum in leaves) and Vec3f
    (three pnanovdb_read_float). Half values are 2-byte aligned in leaves: their word
    address drops the half-word, which the reader takes from the voxel's index
    n, as PNanoVDB's read_half takes it from the byte address.
*/

#pragma once

#include <nanovdb_drjit/layout.h>

#include <cstdint>
#include <tuple>
#include <type_traits>

#include <drjit/array.h>
#include <drjit/while_loop.h>

namespace nanovdb_drjit {

namespace dr = drjit;
using namespace layout;

// ---------------------------------------------------------------------------
//  Constants
// ---------------------------------------------------------------------------

// PNanoVDB: value levels returned by *_get_value_address_and_level
static constexpr uint32_t LEVEL_LEAF       = 0u;
static constexpr uint32_t LEVEL_LOWER      = 1u;
static constexpr uint32_t LEVEL_UPPER      = 2u;
static constexpr uint32_t LEVEL_ROOT_TILE  = 3u;
static constexpr uint32_t LEVEL_BACKGROUND = 4u;

/// Byte offset -> word offset (all offsets used here are multiples of 4)
constexpr uint32_t to_words(uint32_t bytes) { return bytes >> 2; }

/// The layout.h row of a grid type (PNanoVDB: pnanovdb_grid_type_constants[grid_type])
template <uint32_t GridType>
static constexpr const GridTypeConstants &constants_of =
    grid_type_traits<GridType>::constants;

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

/// A Vec3f value: three consecutive floats (PNanoVDB 32.4 reads them with
/// pnanovdb_read_float at address, + 4 and + 8)
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::Array<dr::float32_array_t<UInt32>, 3>
read_vec3f(const Buffer &buf, const UInt32 &address, const dr::mask_t<UInt32> &active) {
    return { read_float(buf, address, active), read_float(buf, UInt32(address + 1u), active),
             read_float(buf, UInt32(address + 2u), active) };
}

/// IEEE binary16 bits (low 16 bits of `bits`) -> float. Exact for every
/// value (each half is a float): normals rebias the exponent, subnormals are
/// m * 2^-24, Inf keeps its sign, NaN its sign and payload made quiet (as
/// x86's F16C conversion does). PNanoVDB's C path stops at the raw bits; its
/// HLSL/GLSL paths call f16tof32 / unpackHalf2x16.
template <typename UInt32>
DRJIT_INLINE dr::float32_array_t<UInt32> half_to_float(const UInt32 &bits) {
    using Float = dr::float32_array_t<UInt32>;
    UInt32 sign = (bits & 0x8000u) << 16, exponent = (bits >> 10) & 0x1fu,
           mantissa = bits & 0x3ffu;
    UInt32 normal = ((exponent + 112u) << 23) | (mantissa << 13),
           special = 0x7f800000u | (mantissa << 13) | dr::select(mantissa != 0u, 0x400000u, 0u);
    Float subnormal = Float(dr::int32_array_t<UInt32>(mantissa)) * 5.9604644775390625e-8f;
    Float magnitude = dr::select(exponent == 0u, subnormal,
                                 dr::reinterpret_array<Float>(
                                     dr::select(exponent == 31u, special, normal)));
    return dr::reinterpret_array<Float>(dr::reinterpret_array<UInt32>(magnitude) | sign);
}

/// PNanoVDB: pnanovdb_read_half, with the half-word given apart: `high`
/// selects the upper 16 bits of the word at `address`
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::float32_array_t<UInt32>
read_half(const Buffer &buf, const UInt32 &address, const UInt32 &high,
          const dr::mask_t<UInt32> &active) {
    return half_to_float(UInt32(read_uint32(buf, address, active) >> (high << 4)));
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

// ---------------------------------------------------------------------------
//  Grid and tree
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_grid_get_tree
template <typename UInt32>
DRJIT_INLINE TreeHandle<UInt32> grid_get_tree(const GridHandle<UInt32> &grid) {
    return { UInt32(grid.address + to_words(GRID_SIZE)) };
}

/// PNanoVDB: pnanovdb_tree_get_root (reads tree.node_offset_root)
template <typename UInt32, typename Buffer>
DRJIT_INLINE RootHandle<UInt32>
tree_get_root(const Buffer &buf, const TreeHandle<UInt32> &tree,
              const dr::mask_t<UInt32> &active = true) {
    UInt32 delta = read_int64_as_word_delta(
        buf, UInt32(tree.address + to_words(TREE_OFF_NODE_OFFSET_ROOT)), active).first;
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
    return read_uint32(buf, UInt32(root.address + to_words(ROOT_OFF_TABLE_SIZE)), active);
}

/// PNanoVDB: pnanovdb_root_get_tile_zero
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE RootTileHandle<UInt32> root_get_tile_zero(const RootHandle<UInt32> &root) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return { UInt32(root.address + to_words(c.root_size)) };
}

/// PNanoVDB: pnanovdb_root_get_tile
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE RootTileHandle<UInt32> root_get_tile(const RootHandle<UInt32> &root,
                                                  const UInt32 &n) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return { UInt32(root.address + to_words(c.root_size) + n * to_words(c.root_tile_size)) };
}

/// PNanoVDB: pnanovdb_root_get_background_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE UInt32 root_get_background_address(const Root &root) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return UInt32(root.address + to_words(c.root_off_background));
}

/// PNanoVDB: pnanovdb_root_tile_get_value_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 root_tile_get_value_address(const RootTileHandle<UInt32> &tile) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return UInt32(tile.address + to_words(c.root_tile_off_value));
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
    constexpr const GridTypeConstants &c = constants_of<GridType>;

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
            UInt32 kx = read_uint32(buf, UInt32(tile + to_words(ROOT_TILE_OFF_KEY)), in_loop),
                   ky = read_uint32(buf, UInt32(tile + to_words(ROOT_TILE_OFF_KEY) + 1u), in_loop);
            Mask match = in_loop & (kx == key_x) & (ky == key_y);
            found = dr::select(match, tile, found);
            tile += to_words(c.root_tile_size);
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
        buf, UInt32(upper.address + to_words(UPPER_OFF_CHILD_MASK) + (bit_index >> 5)),
        active);
    return active & (((value >> (bit_index & 31u)) & 1u) != 0u);
}

/// PNanoVDB: pnanovdb_upper_get_table_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 upper_get_table_address(const UpperHandle<UInt32> &node,
                                            const UInt32 &n) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return UInt32(node.address + to_words(c.upper_off_table) + n * to_words(c.table_stride));
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
        buf, UInt32(lower.address + to_words(LOWER_OFF_CHILD_MASK) + (bit_index >> 5)),
        active);
    return active & (((value >> (bit_index & 31u)) & 1u) != 0u);
}

/// PNanoVDB: pnanovdb_lower_get_table_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 lower_get_table_address(const LowerHandle<UInt32> &node,
                                            const UInt32 &n) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    return UInt32(node.address + to_words(c.lower_off_table) + n * to_words(c.table_stride));
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

/// PNanoVDB: pnanovdb_leaf_get_table_address. In words: a Half value's
/// address is the word that holds it (read_half takes the half-word from n);
/// quantized types have stride 0 (the table's start, as in PNanoVDB).
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 leaf_get_table_address(const LeafHandle<UInt32> &node,
                                           const UInt32 &n) {
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    constexpr uint32_t bits = c.value_stride_bits;
    static_assert(bits % 16 == 0, "values are 0, 16, 32 or 96 bits");
    if constexpr (bits == 0)
        return UInt32(node.address + to_words(c.leaf_off_table));
    else if constexpr (bits % 32 == 0)
        return UInt32(node.address + to_words(c.leaf_off_table) + n * (bits / 32));
    else
        return UInt32(node.address + to_words(c.leaf_off_table) + (n >> 1));
}

/// PNanoVDB: pnanovdb_leaf_get_value_address
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32>
DRJIT_INLINE UInt32 leaf_get_value_address(const LeafHandle<UInt32> &leaf,
                                           const Coord<UInt32> &ijk) {
    return leaf_get_table_address<GridType>(leaf, leaf_coord_to_offset(ijk));
}

/**
 * PNanoVDB: pnanovdb_leaf_fp_read_float. `address` is the leaf's table (the
 * value address of every voxel of a quantized leaf); the code of voxel n is
 * the (n mod values per word)-th field of its word. `value_log_bits` (log2 of
 * the code width) is a constant for Fp4/8/16 and read per leaf for FpN.
 */
template <typename UInt32, typename Buffer, typename LogBits>
DRJIT_INLINE dr::float32_array_t<UInt32>
leaf_fp_read_float(const Buffer &buf, const UInt32 &address, const Coord<UInt32> &ijk,
                   const LogBits &value_log_bits, const dr::mask_t<UInt32> &active) {
    using Float = dr::float32_array_t<UInt32>;
    UInt32 value_bits = UInt32(1u) << value_log_bits,
           value_mask = (UInt32(1u) << value_bits) - 1u,
           values_per_word_bits = UInt32(5u) - value_log_bits,
           values_per_word_mask = (UInt32(1u) << values_per_word_bits) - 1u;
    UInt32 n = leaf_coord_to_offset(ijk);
    Float minimum = read_float(buf, UInt32(address - to_words(LEAF_TABLE_NEG_OFF_MINIMUM)), active),
          quantum = read_float(buf, UInt32(address - to_words(LEAF_TABLE_NEG_OFF_QUANTUM)), active);
    UInt32 raw = read_uint32(buf, UInt32(address + (n >> values_per_word_bits)), active);
    UInt32 code = (raw >> ((n & values_per_word_mask) << value_log_bits)) & value_mask;
    // PNanoVDB: pnanovdb_uint32_to_float(code) * quantum + minimum, unfused
    // (a fused multiply-add would round differently from the C reference)
    Float scaled = Float(dr::int32_array_t<UInt32>(code)) * quantum;
    return scaled + minimum;
}

/// PNanoVDB: pnanovdb_leaf_fpn_read_float (the width from the leaf's flags)
template <typename UInt32, typename Buffer>
DRJIT_INLINE dr::float32_array_t<UInt32>
leaf_fpn_read_float(const Buffer &buf, const UInt32 &address, const Coord<UInt32> &ijk,
                    const dr::mask_t<UInt32> &active) {
    UInt32 bbox_dif_and_flags = read_uint32(
        buf, UInt32(address - to_words(LEAF_TABLE_NEG_OFF_BBOX_DIF_AND_FLAGS)), active);
    UInt32 flags = bbox_dif_and_flags >> 24;
    return leaf_fp_read_float(buf, address, ijk, UInt32(flags >> 5), active);
}

// ---------------------------------------------------------------------------
//  Traversal: value address and level
// ---------------------------------------------------------------------------

/// PNanoVDB: pnanovdb_lower_get_value_address_and_level (inlined: the
/// stencil calls it for each of its 8 corners)
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Buffer>
DRJIT_INLINE AddressAndLevel<UInt32>
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
        buf, UInt32(tile.address + to_words(ROOT_TILE_OFF_CHILD)), found);
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

// ---------------------------------------------------------------------------
//  Reading a value at its address and level
// ---------------------------------------------------------------------------

/**
 * The value index at a value address and level of voxel `ijk` in an OnIndex
 * grid (PNanoVDB 32.6): pnanovdb_leaf_onindex_get_value_index at level 0 --
 * 0 for an inactive voxel, else the leaf's first index plus the active
 * voxels before it (the popcount of its mask word below the voxel, plus the
 * prefix sum of the words before, a 9-bit field of the u64 after the first
 * index) -- and pnanovdb_read_uint64 at the address above (a tile's or the
 * background's index). The low 32 bits: the loader refuses index grids of
 * 2^32 values or more. Inactive lanes return 0.
 */
template <uint32_t GridType, typename Buffer, typename UInt32>
DRJIT_INLINE UInt32 root_read_index(const Buffer &buf, const UInt32 &address,
                                    const UInt32 &level, const Coord<UInt32> &ijk,
                                    const dr::mask_t<UInt32> &active) {
    static_assert(grid_type_traits<GridType>::type.codec == LeafCodec::OnIndex, "an index grid");
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    using Mask = dr::mask_t<UInt32>;
    Mask in_leaf = active & (level == LEVEL_LEAF);
    UInt32 n = leaf_coord_to_offset(ijk);
    // The mask's 32-bit word holding bit n, and the bits below n in it
    UInt32 leaf = UInt32(address - to_words(c.leaf_off_table));
    UInt32 mask_word = read_uint32(buf, UInt32(leaf + to_words(LEAF_OFF_VALUE_MASK) + (n >> 5)),
                                   in_leaf);
    UInt32 bit = UInt32(1u) << (n & 31u);
    Mask on = in_leaf & ((mask_word & bit) != 0u);
    UInt32 sum = dr::popcnt(UInt32(mask_word & (bit - 1u)));
    // The other half of the voxel's 64-bit mask word, when n is in its upper half
    Mask upper_half = on & ((n & 32u) != 0u);
    sum += dr::popcnt(read_uint32(buf, UInt32(leaf + to_words(LEAF_OFF_VALUE_MASK) +
                                              ((n >> 5) & ~1u)), upper_half));
    // The prefix sum of the 64-bit words before: field w - 1 (9 bits each)
    UInt32 word = n >> 6;
    Mask later = on & (word > 0u);
    UInt32 shift = 9u * (word - 1u);
    UInt32 p_lo = read_uint32(buf, UInt32(address + to_words(ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM)), later),
           p_hi = read_uint32(buf, UInt32(address + to_words(ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM) + 1u), later);
    // (p_hi << 1) << (31 - shift): shift = 0 must not shift by 32
    UInt32 field = dr::select(shift < 32u, (p_lo >> (shift & 31u)) | ((p_hi << 1u) << (31u - (shift & 31u))),
                              p_hi >> ((shift - 32u) & 31u));
    sum += dr::select(later, field & 511u, UInt32(0u));
    UInt32 leaf_index = dr::select(on, read_uint32(buf, address, on) + sum, UInt32(0u));
    UInt32 tile_index = read_uint32(buf, address, active & !in_leaf);
    return dr::select(in_leaf, leaf_index, tile_index);
}

/**
 * The scalar value at a value address and level of voxel `ijk`, read as the
 * type's PNanoVDB reader does: pnanovdb_read_float (float);
 * pnanovdb_read_half (Half, every level); pnanovdb_root_fp4/fp8/fp16/fpn_read_float
 * (a float unless level == 0, where the leaf's code is decoded). Inactive
 * lanes return 0.
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename UInt32>
DRJIT_INLINE dr::float32_array_t<UInt32>
root_read_float(const Buffer &buf, const UInt32 &address, const UInt32 &level,
                const Coord<UInt32> &ijk, const dr::mask_t<UInt32> &active) {
    constexpr const ValueType &t = grid_type_traits<GridType>::type;
    static_assert(t.channels == 1, "a scalar type");
    using Mask = dr::mask_t<UInt32>;
    if constexpr (t.codec == LeafCodec::Float32) {
        return read_float(buf, address, active);
    } else if constexpr (t.codec == LeafCodec::OnIndex) {
        // No values in an index grid: its value index, as a float (what a
        // lookup through an array holding i at index i returns; the sampler
        // reads its values array instead)
        return dr::float32_array_t<UInt32>(root_read_index<GridType>(buf, address, level, ijk, active));
    } else if constexpr (t.codec == LeafCodec::Half) {
        UInt32 high = dr::select(level == LEVEL_LEAF, leaf_coord_to_offset(ijk) & 1u, 0u);
        return read_half(buf, address, high, active);
    } else {
        Mask in_leaf = active & (level == LEVEL_LEAF);
        dr::float32_array_t<UInt32> leaf_value;
        if constexpr (t.codec == LeafCodec::Fixed)
            leaf_value = leaf_fp_read_float(buf, address, ijk, t.log2_bits, in_leaf);
        else
            leaf_value = leaf_fpn_read_float(buf, address, ijk, in_leaf);
        return dr::select(in_leaf, leaf_value, read_float(buf, address, active & !in_leaf));
    }
}

/// The 3-vector at a value address (Vec3f: three floats at every level)
template <uint32_t GridType, typename Buffer, typename UInt32>
DRJIT_INLINE dr::Array<dr::float32_array_t<UInt32>, 3>
root_read_vec3f(const Buffer &buf, const UInt32 &address, const dr::mask_t<UInt32> &active) {
    static_assert(grid_type_traits<GridType>::type.codec == LeafCodec::Vec3f, "a Vec3f grid");
    return read_vec3f(buf, address, active);
}

/**
 * The value at `ijk` (PNanoVDB: pnanovdb_root_get_value_address_and_level
 * followed by the type's reader). Values outside the tree are the
 * background, as in every VDB. Inactive lanes return 0.
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32 = decltype(Root::address)>
DRJIT_INLINE dr::float32_array_t<UInt32>
root_get_value(const Buffer &buf, const Root &root,
               const Coord<UInt32> &ijk, const dr::mask_t<UInt32> &active = true) {
    AddressAndLevel<UInt32> al =
        root_get_value_address_and_level<GridType>(buf, root, ijk, active);
    return root_read_float<GridType>(buf, al.address, al.level, ijk, active);
}

} // namespace nanovdb_drjit
