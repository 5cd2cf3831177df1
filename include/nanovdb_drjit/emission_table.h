/*
    nanovdb_drjit/emission_table.h -- where an emissive medium's emission
    distribution lives (issue 35: next-event estimation toward emissive
    volumes)

    Beyond PNanoVDB. Next-event estimation samples a point of an emissive
    medium in proportion to what it emits, sigma_a Le, and needs the pdf of
    any point again for MIS. The table is built on the host from weights
    the medium evaluates (src/loader/emission_table.cpp) over the units of
    the emission grid: its leaves, each cut into 4^3 blocks of 2^3 voxels,
    and its active tiles, each one unit. Sampling: a unit by a CDF, a
    block by its quantized weight, a point uniform in the block (or tile);
    emission_sampling.h reads it on the device. Plain C++: the loader and
    the device code both include it.

    The table, in 32-bit words:

      [0, units]                      the CDF over the units (floats), leaves
                                      first (in leaf array order), then tiles:
                                      cdf[0] = 0, cdf[units] = 1
      leaf_word(units, l) + {0..7,    leaf l's 64 block weights q (4 bits
                                      each, block b at word b / 8, bits
                                      4 (b % 8)),
                             8}       its scale s = (cdf[l + 1] - cdf[l]) / sum(q)
      tile_word(units, leaves, t)     tile t's probability cdf[u + 1] - cdf[u]

    A block's probability is s q_b. The scale is computed from the stored
    floats, with the same arithmetic as sampling picks the unit, so a
    sampled point's pdf and the pdf recomputed for it are the same number.
    q is the block's weight as a fraction of the leaf's largest block,
    rounded up to 1..15 (0 only for a block of weight 0): no emitting block
    is left out. The model that chose 2^3 blocks and 4 bits (1.09x the
    variance of a float per voxel, at 1.65 % of the grid's bytes):
    bench/results/emission_nee_model.md.
*/

#pragma once

#include <cstdint>

namespace nanovdb_drjit {

/// Blocks per leaf (4^3 blocks of 2^3 voxels) and their words (8 per word)
static constexpr uint32_t EMISSION_BLOCKS = 64;
static constexpr uint32_t EMISSION_BLOCK_WORDS = EMISSION_BLOCKS / 8;
/// A leaf's words: its blocks' weights, then its scale
static constexpr uint32_t EMISSION_LEAF_WORDS = EMISSION_BLOCK_WORDS + 1;
/// The largest quantized block weight (4 bits)
static constexpr uint32_t EMISSION_LEVELS = 15;

/// The block of a leaf's voxel, from its local coordinates (0..7 each)
constexpr uint32_t emission_block(uint32_t i, uint32_t j, uint32_t k) {
    return ((i >> 1) << 4) | ((j >> 1) << 2) | (k >> 1);
}

/// The first word of leaf l's entry
constexpr uint32_t emission_leaf_word(uint32_t units, uint32_t l) {
    return units + 1 + EMISSION_LEAF_WORDS * l;
}

/// The word of tile t (the unit leaves + t)
constexpr uint32_t emission_tile_word(uint32_t units, uint32_t leaves, uint32_t t) {
    return units + 1 + EMISSION_LEAF_WORDS * leaves + t;
}

} // namespace nanovdb_drjit
