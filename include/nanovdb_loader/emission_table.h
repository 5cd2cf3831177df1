/*
    nanovdb_loader/emission_table.h -- builds an emissive medium's emission
    distribution (the table of nanovdb_drjit/emission_table.h) from its
    weights
*/

#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace nanovdb_loader {

struct EmissionTable {
    uint32_t leaf_count = 0, tile_count = 0;
    double total = 0.0;          ///< the sum of the weights (the emitted power)
    std::vector<uint32_t> words; ///< nanovdb_drjit/emission_table.h's layout
    /// The table's bytes
    size_t bytes() const { return words.size() * 4; }
};

/**
 * The table from the units' weights: `leaf_weights`, 512 per leaf (a
 * leaf's voxels in NanoVDB's order, n = 64 i + 8 j + k), each what its
 * voxel emits (max channel of sigma_a Le times its volume); `tile_weights`,
 * one per active tile, what the whole tile emits. Throws
 * std::invalid_argument for a weight that is negative or not finite (the
 * caller names the file), and for a total of 0 (nothing to sample: the
 * caller turns next-event estimation off and says so).
 */
EmissionTable build_emission_table(const std::vector<float> &leaf_weights,
                                   const std::vector<float> &tile_weights);

} // namespace nanovdb_loader
