/*
    nanovdb_drjit/emission_sampling.h -- sampling an emissive medium's
    emission table (emission_table.h) and the probability of a block again

    Beyond PNanoVDB. Every backend: Table is a JIT UInt32 array or, on the
    scalar path, a host pointer (as the majorant table's reads). A sample
    is a unit (a leaf or a tile of the emission grid) by the CDF, then, in a
    leaf, a block by its 4-bit weight; the caller places a point uniform in
    the block or tile (the emission grid's index space, then its map to
    world) and divides the probability by that region's volume.
*/

#pragma once

#include <nanovdb_drjit/emission_table.h>
#include <nanovdb_drjit/pnanovdb.h>

namespace nanovdb_drjit {

template <typename UInt32> struct EmissionPick {
    using Float = dr::float32_array_t<UInt32>;
    UInt32 unit;  ///< the leaf (unit < leaves) or tile (leaves + t)
    UInt32 block; ///< in a leaf, its block (emission_block); 0 in a tile
    Float prob;   ///< the probability of the unit and block
    Float rest;   ///< what is left of the random number, uniform in [0, 1)
};

/**
 * The last i in [0, n) with key(i, mask) <= x (0 where none is), for keys
 * that do not decrease with i: a branchless binary search whose steps are
 * unrolled for the host's n. (The emission table's CDF; a grid's sorted
 * tile addresses, nanovdbvolume's locate_unit)
 */
template <typename UInt32, typename Key, typename T>
DRJIT_INLINE UInt32 last_at_most(uint32_t n, Key &&key, const T &x,
                                 const dr::mask_t<UInt32> &active) {
    UInt32 u = 0;
    uint32_t step = 1;
    while (step * 2 <= n)
        step *= 2;
    for (; step > 0; step /= 2) {
        const UInt32 c = u + step;
        const dr::mask_t<UInt32> ok = active && c < n;
        dr::masked(u, ok && key(c, ok) <= x) = c;
    }
    return u;
}

namespace detail {

/// The sum of the eight 4-bit fields of a word
template <typename UInt32> DRJIT_INLINE UInt32 nibble_sum(const UInt32 &w) {
    UInt32 bytes = (w & 0x0f0f0f0fu) + ((w >> 4) & 0x0f0f0f0fu);
    return (bytes * 0x01010101u) >> 24;
}

} // namespace detail

/**
 * The probability of block `block` of leaf `leaf` (s q_b), or of tile
 * `unit - leaves` (block ignored): the number sampling returns for it.
 */
template <typename UInt32, typename Table>
DRJIT_INLINE dr::float32_array_t<UInt32>
emission_probability(const Table &table, uint32_t units, uint32_t leaves, const UInt32 &unit,
                     const UInt32 &block, const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    const Mask leaf = active && unit < leaves;
    const UInt32 base = units + 1 + EMISSION_LEAF_WORDS * unit;
    const UInt32 word = read_uint32(table, UInt32(base + (block >> 3)), leaf);
    const UInt32 q = (word >> ((block & 7u) << 2)) & 0xfu;
    const auto scale = read_float(table, UInt32(base + EMISSION_BLOCK_WORDS), leaf);
    // (a tile's word: after the leaves' entries)
    const UInt32 tile_word = units + 1 + EMISSION_LEAF_WORDS * leaves + (unit - leaves);
    const auto tile = read_float(table, tile_word, active && !leaf);
    return dr::select(leaf, scale * dr::float32_array_t<UInt32>(q), tile);
}

/**
 * A unit and block for the random number x in [0, 1). `units` and
 * `leaves` are the table's (host values: the search's steps are unrolled
 * for them).
 */
template <typename UInt32, typename Table>
EmissionPick<UInt32> sample_emission(const Table &table, uint32_t units, uint32_t leaves,
                                     const dr::float32_array_t<UInt32> &x,
                                     const dr::mask_t<UInt32> &active) {
    using Float = dr::float32_array_t<UInt32>;
    using Mask = dr::mask_t<UInt32>;
    // The unit: the last u in [0, units) with cdf[u] <= x (branchless
    // binary search; units of probability 0 are never chosen, as their
    // successor has the same cdf)
    const UInt32 u = last_at_most<UInt32>(
        units, [&](const UInt32 &c, const Mask &ok) { return read_float(table, c, ok); }, x,
        active);
    const Float lo = read_float(table, u, active),
                hi = read_float(table, UInt32(u + 1u), active);
    Float rest = dr::minimum((x - lo) / (hi - lo), dr::OneMinusEpsilon<Float>);

    // In a leaf: the block, by its weight q (the eight words' sums, then
    // the fields of the word that holds the target)
    const Mask leaf = active && u < leaves;
    const UInt32 base = units + 1 + EMISSION_LEAF_WORDS * u;
    UInt32 words[EMISSION_BLOCK_WORDS], sums[EMISSION_BLOCK_WORDS];
    UInt32 total = 0;
    for (uint32_t w = 0; w < EMISSION_BLOCK_WORDS; ++w) {
        words[w] = read_uint32(table, UInt32(base + w), leaf);
        sums[w] = detail::nibble_sum(words[w]);
        total += sums[w];
    }
    // target in [0, total): the block b whose [before, before + q_b) holds
    // it. Intervals of weight 0 are empty and never chosen; the last
    // non-empty one takes a target that rounding put at its end
    const Float t = rest * Float(total);
    UInt32 word = 0, before = 0, chosen = words[0], end = 0;
    Mask found = !leaf;
    for (uint32_t w = 0; w < EMISSION_BLOCK_WORDS; ++w) {
        const UInt32 after = before + sums[w];
        const Mask here = !found && sums[w] > 0u && (t < Float(after) || after == total);
        dr::masked(word, here) = w;
        dr::masked(chosen, here) = words[w];
        dr::masked(end, here) = after;
        found |= here;
        dr::masked(before, !found) = after;
    }
    UInt32 field = 0, q = 0;
    found = !leaf;
    for (uint32_t f = 0; f < 8; ++f) {
        const UInt32 qf = (chosen >> (4 * f)) & 0xfu;
        const Mask here = !found && qf > 0u && (t < Float(before + qf) || before + qf == end);
        dr::masked(field, here) = f;
        dr::masked(q, here) = qf;
        found |= here;
        dr::masked(before, !found) += qf;
    }
    dr::masked(rest, leaf) =
        dr::minimum((t - Float(before)) / Float(q), dr::OneMinusEpsilon<Float>);
    UInt32 block = dr::select(leaf, word * 8u + field, 0u);
    EmissionPick<UInt32> pick{ u, block, emission_probability(table, units, leaves, u, block, active),
                               rest };
    return pick;
}

} // namespace nanovdb_drjit
