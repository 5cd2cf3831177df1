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

      [0, leaf_slots)                         one per leaf, in leaf array order
                                              (FpN: one per 160 bytes of leaves)
      lower_slot + 2148 n + {0, 1, 2,         lower node n: M, R, m,
                             3 + b,           brick b's M,
                             67 + b / 4,      brick b's m (8 bits, byte b % 4),
                             83 + e / 4,      entry e's bound (8 bits, byte e % 4)
                             1107 + e / 4,    entry e's control (8 bits, byte e % 4)
                             2131 + b / 4,    brick b's control (8 bits, byte b % 4)
                             2147}            the node's control (32 bits)
      upper_slot + 4 n + {0, 1, 2, 3}         upper node n: M, R, m, its control (32 bits)
      tile_slot + t                           root tile t, in table order
      background_slot                         the background

    M bounds the node's whole region; R is the node's "ring bound" for its
    tiles: a tile of value v is bounded by max(v, R); m is the smallest value
    the node stores (without ring: not a bound, a measure of how uniform the
    node is -- M - m small means crossing it whole adds few null collisions,
    however large M is). A leaf's slot bounds
    its 8^3 voxels. A lower node is also cut into 4^3 bricks of 32^3 voxels
    (b = x-major brick index), each with its own M and m (m as a fraction
    q / 255 of the brick's M, rounded down, four bricks to a slot: like the
    node's m a measure, not a bound, so 8 bits do): a level between the
    lower node and its leaves that lets a walk cross thin parts of a node
    in larger steps. Each of its 16^3 entries (a leaf or a tile) has its
    own bound, its ringed region's max, as an 8-bit fraction q / 255 of its
    brick's M, rounded up (child_bound): a walk's step inside a lower node
    reads one word of the table, not the node's child mask, its entry and
    the leaf's slot (4 KiB per lower node). See nanovdb_loader/majorants.h
    for the exact definitions.

    Controls (residual ratio tracking, src/integrators/tracking.h) give a
    cell two more numbers below its bound M: c, the mean of its voxels,
    and L, a lower bound of every value a lookup can return in its ringed
    region (as M is an upper bound). Each is a fraction of the cell's own
    bound as the walk computes it (an entry's: child_bound, a brick's M,
    the node's M), so the table's scale (spectral factor, 1 + 2^-20) needs
    no rewrite: an entry's and a brick's in one byte (c in the high four
    bits, rounded; L in the low four, rounded down), a node's in one word
    (16 bits each): control_bits<4 or 16> writes them, control_of reads them. Upper tiles take their value
    as c and 0 as L; root tiles and the background 0 and 0 (ratio tracking
    there). Residual tracking samples the cells at rate max(M - c, c - L),
    which is 0 only where M = c = L, i.e. where the value is constant.
    The model that chose 4 bits: bench/results/transmittance_estimators.md.

    A slot is found from the node's word address without a search: node
    arrays are contiguous with a fixed stride per level (validation checks
    it), so slot = first slot + (address - array begin) / node words, a
    division by a per-type constant (a multiply-high on the device). FpN
    leaves differ in size (160 to 1120 bytes, by their code width): their
    slots are per 160 bytes of the leaf array, one at each leaf's start and
    the others unused (4 bytes per 160: 2.5 % of the leaf bytes, against
    0.2 % for fixed sizes).
*/

#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

namespace nanovdb_drjit {

/// The factor of every bound as the walk reads it (MajorantGrid::make):
/// 1 + 2^-20, for the few ulps by which rounded trilinear weights overshoot
static constexpr float MAJORANT_SCALE = 1.f + 0x1p-20f;

/// A lower node's bricks: 4^3 bricks of 32^3 voxels (4^3 of its entries)
static constexpr uint32_t BRICK_LOG2_DIM = 5;
static constexpr uint32_t LOWER_BRICK_COUNT = 64;
/// Slots per lower node: M, R, m, one M per brick, then the bricks' m as
/// 8-bit fractions of their M, four to a slot; per upper node: M, R, m
static constexpr uint32_t LOWER_BRICK_M_SLOT = 3;
static constexpr uint32_t LOWER_BRICK_FRACTION_SLOT = LOWER_BRICK_M_SLOT + LOWER_BRICK_COUNT;
/// Then the bounds of its 16^3 entries as 8-bit fractions of their brick's
/// M, four to a slot
static constexpr uint32_t LOWER_ENTRY_COUNT = 4096;
static constexpr uint32_t LOWER_ENTRY_FRACTION_SLOT = LOWER_BRICK_FRACTION_SLOT + LOWER_BRICK_COUNT / 4;
/// Then the controls (c and L) of its entries and bricks, a byte each, four
/// to a slot, and the node's, one slot
static constexpr uint32_t LOWER_ENTRY_CONTROL_SLOT = LOWER_ENTRY_FRACTION_SLOT + LOWER_ENTRY_COUNT / 4;
static constexpr uint32_t LOWER_BRICK_CONTROL_SLOT = LOWER_ENTRY_CONTROL_SLOT + LOWER_ENTRY_COUNT / 4;
static constexpr uint32_t LOWER_CONTROL_SLOT = LOWER_BRICK_CONTROL_SLOT + LOWER_BRICK_COUNT / 4;
static constexpr uint32_t LOWER_SLOTS = LOWER_CONTROL_SLOT + 1;
/// Per upper node: M, R, m, then its control
static constexpr uint32_t UPPER_CONTROL_SLOT = 3;
static constexpr uint32_t UPPER_SLOTS = UPPER_CONTROL_SLOT + 1;

/// The brick (0..63) of a lower node that holds local coordinate ijk & 127
constexpr uint32_t brick_of(uint32_t i, uint32_t j, uint32_t k) {
    return (((i & 127u) >> BRICK_LOG2_DIM) << 4) | (((j & 127u) >> BRICK_LOG2_DIM) << 2) |
           ((k & 127u) >> BRICK_LOG2_DIM);
}

/// A brick's m from its M and its 8-bit fraction q (the device and the tests
/// compute it so, bit for bit)
inline float brick_min(float M, uint32_t q) { return M * (float(q) / 255.f); }

/// The 8-bit fraction stored for a brick with max M and min m
inline uint32_t brick_fraction(float M, float m) {
    if (!(M > 0.f) || !(m > 0.f))
        return 0;
    if (m >= M)
        return 255;
    const float q = 255.f * (m / M);
    return q >= 255.f ? 254u : uint32_t(q); // below 255: m < M stays visible
}

/// An entry's bound from its brick's M and its 8-bit fraction q (the device
/// and the tests compute it so, bit for bit: q = 255 gives M itself, as
/// 255 * (1 / 255.f) rounds to 1; q = 0 gives 0, also where M is +-Inf)
inline float child_bound(float M, uint32_t q) {
    return q == 0 ? 0.f : (M > 0.f ? M : 0.f) * (float(q) * (1.f / 255.f));
}

/// The 8-bit fraction stored for an entry whose ringed region's max is r, in
/// a brick of bound M >= r: the smallest q whose child_bound covers r with a
/// margin of 2^-12 (the rounding of the device's two products, and of the
/// walk's scaled copy of M, stays far below it)
inline uint32_t child_fraction(float M, float r) {
    if (!(r > 0.f) || !(M > 0.f))
        return 0;
    const double want = double(r) * (1.0 + 1.0 / 4096.0);
    for (uint32_t q = uint32_t(std::max(0.0, std::floor(255.0 * want / double(M)))); q < 255; ++q)
        if (double(child_bound(M, q)) >= want)
            return q;
    return 255;
}

/// A cell's control c and lower bound L from its bound M and their bits
/// (control_byte's four and four, or control_word's 16 and 16): the device
/// and the tests compute them so
template <uint32_t Bits, typename Value, typename Word>
inline auto control_of(const Value &M, const Word &bits) {
    constexpr uint32_t mask = (1u << Bits) - 1u;
    constexpr float unit = 1.f / float(mask);
    return std::make_pair(M * (Value((bits >> Bits) & mask) * unit),
                          M * (Value(bits & mask) * unit));
}

/// The bits of a cell of bound M whose voxels' mean is c and whose ringed
/// region's smallest value is L (<= c): c rounded, L rounded down, each a
/// fraction of M in [0, 1], so that the device's L stays at most the true
/// one (to the rounding of one product). Bits = 4: a byte; 16: a word.
template <uint32_t Bits> inline uint32_t control_bits(float M, float c, float L) {
    constexpr uint32_t top = (1u << Bits) - 1u;
    if (!(M > 0.f) || std::isinf(M))
        return 0;
    auto frac = [M](float v) { return std::clamp(double(v) / double(M), 0.0, 1.0); };
    const uint32_t qc = uint32_t(std::lround(frac(c) * top));
    uint32_t ql = uint32_t(std::floor(frac(L) * top));
    if (ql == top && !(L >= M)) // (the rounding of L / M)
        ql = top - 1;
    return (qc << Bits) | std::min(ql, qc);
}

/// Where the bounds of a grid's nodes sit in its majorant array
struct MajorantTableLayout {
    uint32_t leaf_begin_word  = 0; ///< word address of the first leaf
    uint32_t lower_begin_word = 0; ///< ... of the first lower node
    uint32_t upper_begin_word = 0; ///< ... of the first upper node
    uint32_t tile_begin_word  = 0; ///< ... of the first root tile
    uint32_t leaf_slot_words  = 1; ///< words of leaf array per leaf slot
    uint32_t lower_slot = 0, upper_slot = 0, tile_slot = 0, background_slot = 0;
    uint32_t size = 0;             ///< slots in all

    /// The slot of the leaf at word address `leaf_word`
    uint32_t leaf_slot(uint32_t leaf_word) const {
        return (leaf_word - leaf_begin_word) / leaf_slot_words;
    }

    /// The layout for a grid with these node counts and arrays; leaf slots
    /// of `leaf_slot_bytes` (the leaf size, FPN_MIN_LEAF_SIZE for FpN)
    static MajorantTableLayout make(const uint64_t node_begin[3], const uint64_t node_end[3],
                                    const uint32_t node_count[3], uint32_t root_word,
                                    uint32_t root_size, uint32_t root_tile_count,
                                    uint32_t leaf_slot_bytes) {
        MajorantTableLayout t;
        t.leaf_begin_word  = uint32_t(node_begin[0] / 4);
        t.lower_begin_word = uint32_t(node_begin[1] / 4);
        t.upper_begin_word = uint32_t(node_begin[2] / 4);
        t.tile_begin_word  = root_word + root_size / 4;
        t.leaf_slot_words  = leaf_slot_bytes / 4;
        t.lower_slot       = node_count[0] == 0 ? 0u
                             : uint32_t((node_end[0] - node_begin[0]) / leaf_slot_bytes);
        t.upper_slot       = t.lower_slot + LOWER_SLOTS * node_count[1];
        t.tile_slot        = t.upper_slot + UPPER_SLOTS * node_count[2];
        t.background_slot  = t.tile_slot + root_tile_count;
        t.size             = t.background_slot + 1;
        return t;
    }
};

} // namespace nanovdb_drjit
