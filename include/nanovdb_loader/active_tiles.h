/*
    nanovdb_loader/active_tiles.h -- the active tiles of a grid (root,
    upper and lower tiles without a child, whose value-mask bit or root
    state is set): where they are and which value lookups read for them.
    For an emissive medium's next-event estimation (issue 35), whose table
    holds a grid's leaves and these tiles (nanovdb_drjit/emission_table.h).
*/

#pragma once

#include <nanovdb_loader/validation.h>

#include <cstdint>
#include <vector>

namespace nanovdb_loader {

struct ActiveTile {
    int32_t origin[3];   ///< its first voxel (index space)
    uint32_t log2dim;    ///< voxels per axis: 3 (lower tile, 8^3), 7 (upper, 128^3), 12 (root)
    uint32_t value_word; ///< the word address of its value in the grid (PNanoVDB's
                         ///< value address of every coordinate inside it, / 4)
};

/// Every active tile that lookups reach, sorted by value_word. Inactive
/// tiles are left out, whatever they hold.
std::vector<ActiveTile> active_tiles(const ValidatedGrid &grid);

} // namespace nanovdb_loader
