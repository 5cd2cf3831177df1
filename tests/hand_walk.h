// tests/hand_walk.h -- the majorant walk done by hand on the host: the bound
// of the finest cell the walk (include/nanovdb_drjit/majorant_walk.h) uses
// at a voxel, found through NanoVDB's own node structs (an independent
// traversal) and the loader's majorant table, with coarse_limit = 0 (only
// nodes and bricks of one value, M - m <= 0, are crossed whole). Shared by
// tests/test_majorant_walk.cpp (each segment's bound) and
// tests/io/test_node_majorants.cpp (mean_bound).
#pragma once

#include <nanovdb/NanoVDB.h>
#include <nanovdb_drjit/majorant_table.h>
#include <nanovdb_loader/majorants.h>

#include <algorithm>
#include <cstring>
#include <vector>

namespace nvdb_test {

/// The bound of the finest cell holding absolute voxel ijk, by hand: NanoVDB's
/// node structs find the node, the loader's table gives its bound (nodes and
/// bricks with M - m <= 0 are crossed whole, as the walk does with
/// coarse_limit = 0)
inline float finest_bound(const nanovdb::FloatGrid &grid, const nanovdb_loader::NodeMajorants &maj,
                         const nanovdb::Coord &ijk) {
    namespace ndr = nanovdb_drjit;
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    const auto &L = maj.layout;
    const std::vector<float> &m = maj.values;
    auto clamp0 = [](float v) { return std::max(v, 0.f); };
    const nanovdb::Coord block = ijk & ~4095;
    for (uint32_t t = 0; t < root.tileCount(); ++t) {
        const auto *tile = root.data()->tile(t);
        if (tile->origin() != block)
            continue;
        if (!tile->isChild())
            return clamp0(m[L.tile_slot + t]);
        const auto *up = root.data()->getChild(tile);
        const uint32_t uslot = L.upper_slot + ndr::UPPER_SLOTS * uint32_t(up - tree.getFirstNode<2>());
        // A node of one value (M - m <= 0) is crossed whole, with its M
        if (!(m[uslot] - m[uslot + 2] > 0.f))
            return clamp0(m[uslot]);
        const uint32_t nu = up->CoordToOffset(ijk);
        if (!up->data()->isChild(nu))
            return clamp0(std::max(up->data()->getValue(nu), m[uslot + 1]));
        const auto *lo = up->data()->getChild(nu);
        const uint32_t slot = L.lower_slot + ndr::LOWER_SLOTS * uint32_t(lo - tree.getFirstNode<1>());
        if (!(m[slot] - m[slot + 2] > 0.f))
            return clamp0(m[slot]);
        const uint32_t b = ndr::brick_of(uint32_t(ijk[0]), uint32_t(ijk[1]), uint32_t(ijk[2]));
        const float brick = m[slot + ndr::LOWER_BRICK_M_SLOT + b];
        uint32_t fractions;
        std::memcpy(&fractions, &m[slot + ndr::LOWER_BRICK_FRACTION_SLOT + b / 4], 4);
        if (!(brick - ndr::brick_min(brick, (fractions >> (8 * (b % 4))) & 255u) > 0.f))
            return clamp0(brick);
        // A leaf or a tile: its entry's fraction of the brick's M
        const uint32_t nl = lo->CoordToOffset(ijk);
        std::memcpy(&fractions, &m[slot + ndr::LOWER_ENTRY_FRACTION_SLOT + nl / 4], 4);
        return ndr::child_bound(brick, (fractions >> (8 * (nl % 4))) & 255u);
    }
    return clamp0(m[L.background_slot]);
}

} // namespace nvdb_test
