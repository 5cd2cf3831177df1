// Named test volumes as NanoVDB grids (NanoVDB's own openToNanoVDB) and their
// query coordinates. See grids.h.

#include "grids.h"

#include <algorithm>
#include <limits>
#include <stdexcept>

#include <nanovdb/util/OpenToNanoVDB.h>

#include "testdata/seeded.h"

namespace nvdb_test {

namespace {

using nvdb_testdata::Rng;

// Catalogue of a NanoVDB grid's nodes and tiles, for query_coords().

using NanoRootF = nanovdb::NanoRoot<float>;
using NanoUpperF = nanovdb::NanoUpper<float>;
using NanoLowerF = nanovdb::NanoLower<float>;
using NanoLeafF = nanovdb::NanoLeaf<float>;

struct Region {
    nanovdb::Coord origin;
    int64_t dim;
};

struct ActiveLeaf {
    nanovdb::Coord origin;
    const NanoLeafF *leaf;
    uint32_t count; // active voxels
};

struct Catalogue {
    std::vector<Region> nodes[4];       // leaf, lower, upper nodes; root tiles
    std::vector<Region> valued_tiles[4]; // [1..3]: tiles active or != background
    std::vector<ActiveLeaf> active_leaves;
};

/// Origins come from the parent (root key, table offset), not from the
/// node's own bbox, which is the bbox of its active values.
template <typename NodeT>
nanovdb::Coord child_origin(const nanovdb::Coord &parent_origin, uint32_t n) {
    nanovdb::Coord local = NodeT::OffsetToLocalCoord(n);
    local <<= NodeT::ChildNodeType::TOTAL;
    return parent_origin + local;
}

template <typename NodeT, typename ChildVisitor>
void visit_internal(const NodeT &node, const nanovdb::Coord &origin, float background,
                    int level, Catalogue &cat, ChildVisitor visit_child) {
    const auto *data = node.data();
    const int64_t tile_dim = int64_t(NodeT::ChildNodeType::DIM);
    for (uint32_t n = 0; n < NodeT::SIZE; ++n) {
        const nanovdb::Coord o = child_origin<NodeT>(origin, n);
        if (data->isChild(n))
            visit_child(*data->getChild(n), o);
        else if (data->isActive(n) || data->getValue(n) != background)
            cat.valued_tiles[level].push_back({ o, tile_dim });
    }
}

Catalogue catalogue(const nanovdb::NanoGrid<float> &grid) {
    Catalogue cat;
    const auto *root = grid.tree().root().data();
    const float background = root->mBackground;
    for (uint32_t t = 0; t < root->mTableSize; ++t) {
        const auto *tile = root->tile(t);
        const nanovdb::Coord upper_origin = tile->origin();
        if (!tile->isChild()) {
            cat.nodes[3].push_back({ upper_origin, NanoUpperF::DIM });
            if (tile->state || tile->value != background)
                cat.valued_tiles[3].push_back({ upper_origin, NanoUpperF::DIM });
            continue;
        }
        cat.nodes[2].push_back({ upper_origin, NanoUpperF::DIM });
        visit_internal(*root->getChild(tile), upper_origin, background, 2, cat,
                       [&](const NanoLowerF &lower, const nanovdb::Coord &lower_origin) {
            cat.nodes[1].push_back({ lower_origin, NanoLowerF::DIM });
            visit_internal(lower, lower_origin, background, 1, cat,
                           [&](const NanoLeafF &leaf, const nanovdb::Coord &leaf_origin) {
                cat.nodes[0].push_back({ leaf_origin, NanoLeafF::DIM });
                if (uint32_t count = leaf.valueMask().countOn())
                    cat.active_leaves.push_back({ leaf_origin, &leaf, count });
            });
        });
    }
    return cat;
}

int32_t clamp_int32(int64_t v) {
    return int32_t(std::clamp<int64_t>(v, std::numeric_limits<int32_t>::min(),
                                       std::numeric_limits<int32_t>::max()));
}

/// Offset within a leaf of its `index`-th active voxel (0-based).
uint32_t nth_active(const NanoLeafF &leaf, uint32_t index) {
    const auto &mask = leaf.valueMask();
    for (uint32_t w = 0; w < mask.wordCount(); ++w) {
        uint64_t word = mask.getWord<uint64_t>(int(w));
        const uint32_t count = uint32_t(__builtin_popcountll(word));
        if (index >= count) {
            index -= count;
            continue;
        }
        for (; index > 0; --index)
            word &= word - 1; // drop the lowest set bit
        return w * 64 + uint32_t(__builtin_ctzll(word));
    }
    throw std::logic_error("nth_active: index past the active count");
}

} // namespace

nanovdb::GridHandle<nanovdb::HostBuffer> make_nano_grid(const std::string &name, int scale) {
    openvdb::FloatGrid::Ptr grid = make_vdb_grid(name, scale);
    return nanovdb::openToNanoVDB(*grid);
}

std::vector<std::array<int32_t, 3>> query_coords(const nanovdb::NanoGrid<float> &grid,
                                                 size_t n, uint64_t seed) {
    const Catalogue cat = catalogue(grid);
    Rng rng = Rng::counter(seed);

    std::vector<int> tile_levels, node_levels;
    for (int level = 1; level <= 3; ++level)
        if (!cat.valued_tiles[level].empty())
            tile_levels.push_back(level);
    for (int level = 0; level <= 3; ++level)
        if (!cat.nodes[level].empty())
            node_levels.push_back(level);

    // Index bbox grown by 16. An empty grid's bbox is inverted (min > max):
    // use [-16, 16]^3 around the origin instead.
    const nanovdb::CoordBBox bbox = grid.indexBBox();
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        const bool empty = bbox.min()[a] > bbox.max()[a];
        lo[a] = empty ? -16 : int64_t(bbox.min()[a]) - 16;
        hi[a] = empty ? 16 : int64_t(bbox.max()[a]) + 16;
        lo[a] = clamp_int32(lo[a]);
        hi[a] = clamp_int32(hi[a]);
    }

    static const int32_t extremes[] = {
        std::numeric_limits<int32_t>::min(),     std::numeric_limits<int32_t>::min() + 1,
        std::numeric_limits<int32_t>::max(),     std::numeric_limits<int32_t>::max() - 1,
        -std::numeric_limits<int32_t>::max(),    -(std::numeric_limits<int32_t>::max() - 1),
        std::numeric_limits<int32_t>::min() + 4096, std::numeric_limits<int32_t>::max() - 4095,
        -(1 << 30),                              1 << 30,
        0,                                       -1,
    };
    const size_t extreme_count = sizeof(extremes) / sizeof(extremes[0]);

    // Shares of the four classes (1) active, (2) near the bbox, (3) far,
    // (4) node boundaries; absent classes get weight 0.
    const bool have_active = !cat.active_leaves.empty() || !tile_levels.empty();
    const double weights[4] = { have_active ? 0.3 : 0.0, 0.3, 0.1,
                                node_levels.empty() ? 0.0 : 0.3 };
    const double total = weights[0] + weights[1] + weights[2] + weights[3];

    std::vector<std::array<int32_t, 3>> out;
    out.reserve(n);
    for (size_t q = 0; q < n; ++q) {
        double pick = rng.uniform() * total;
        int cls = 0;
        while (cls < 3 && (pick >= weights[cls] || weights[cls] == 0.0)) {
            pick -= weights[cls];
            ++cls;
        }
        if (cls == 3 && node_levels.empty()) // rounding at the very end of `total`
            cls = 1;
        std::array<int32_t, 3> ijk{};
        switch (cls) {
            case 0: { // active voxel, or a point inside an active/valued tile
                const bool voxel = tile_levels.empty() ||
                                   (!cat.active_leaves.empty() && rng.below(2) == 0);
                if (voxel) {
                    const ActiveLeaf &l = cat.active_leaves[rng.below(cat.active_leaves.size())];
                    const uint32_t off = nth_active(*l.leaf, uint32_t(rng.below(l.count)));
                    ijk = { l.origin[0] + int32_t(off >> 6), l.origin[1] + int32_t((off >> 3) & 7),
                            l.origin[2] + int32_t(off & 7) };
                } else {
                    const auto &tiles = cat.valued_tiles[tile_levels[rng.below(tile_levels.size())]];
                    const Region &t = tiles[rng.below(tiles.size())];
                    for (int a = 0; a < 3; ++a)
                        ijk[a] = clamp_int32(int64_t(t.origin[a]) + int64_t(rng.below(uint64_t(t.dim))));
                }
                break;
            }
            case 1: // near the bbox
                for (int a = 0; a < 3; ++a)
                    ijk[a] = int32_t(rng.range(lo[a], hi[a]));
                break;
            case 2: // far: full int32 range with its extremes
                for (int a = 0; a < 3; ++a)
                    ijk[a] = rng.below(4) == 0 ? extremes[rng.below(extreme_count)]
                                               : int32_t(uint32_t(rng.next() >> 32));
                break;
            default: { // node boundaries: origin-1, origin, origin+dim-1, origin+dim
                const auto &nodes = cat.nodes[node_levels[rng.below(node_levels.size())]];
                const Region &r = nodes[rng.below(nodes.size())];
                for (int a = 0; a < 3; ++a) {
                    const int64_t o = r.origin[a];
                    int64_t v;
                    switch (rng.below(5)) {
                        case 0: v = o - 1; break;
                        case 1: v = o; break;
                        case 2: v = o + r.dim - 1; break;
                        case 3: v = o + r.dim; break;
                        default: v = o + int64_t(rng.below(uint64_t(r.dim))); break;
                    }
                    ijk[a] = clamp_int32(v);
                }
                break;
            }
        }
        out.push_back(ijk);
    }
    return out;
}

} // namespace nvdb_test
