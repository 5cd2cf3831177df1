// src/loader/rebuild_plan.cpp -- majorant_rebuild_plan() (see majorants.h):
// the tree's part of node_majorants, read once at load, for the backend's
// rebuild after an index grid's values change (nanovdb_drjit/rebuild_plan.h).
//
// What node_majorants finds with TreeView::find (the node or the value that
// covers a neighbouring cell) is recorded here as codes, one per node-sized
// cell around each node and each root tile, and one per entry; the values
// are left to the backend.

#include <nanovdb_loader/majorants.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"

#include <algorithm>

namespace nanovdb_loader {

using namespace detail;
namespace ndr = nanovdb_drjit;

std::optional<ndr::MajorantRebuildPlan> majorant_rebuild_plan(const ValidatedGrid &grid, int ring,
                                                              std::string *why) {
    auto refuse = [why](const char *reason) -> std::optional<ndr::MajorantRebuildPlan> {
        if (why)
            *why = reason;
        return std::nullopt;
    };
    const GridSummary &s = grid.summary();
    if (!grid.is_index_grid())
        return refuse("not an index grid");
    // (codes are int32: -1 - value index)
    if (grid.index_values().count >= uint64_t(INT32_MAX))
        return refuse("2^31 values or more");
    if (s.node_count[0] == 0 || s.node_count[1] == 0 || s.node_count[2] == 0)
        return refuse("no leaves");
    const TreeView view(grid);
    const uint8_t *buf = grid.data();
    const layout::GridTypeConstants &c = layout::GRID_TYPE_CONSTANTS_ONINDEX;

    ndr::MajorantRebuildPlan p;
    p.layout = ndr::MajorantTableLayout::make(s.node_begin, s.node_end, s.node_count, s.root_word,
                                              c.root_size, s.root_tile_count, c.leaf_size);
    p.ring = uint32_t(std::clamp(ring, 1, 8));
    p.leaf_count = uint32_t(s.node_count[0]);
    p.lower_count = uint32_t(s.node_count[1]);
    p.upper_count = uint32_t(s.node_count[2]);
    p.leaf_words = c.leaf_size / 4;
    auto index_at = [&](uint64_t at) { return load<uint64_t>(buf + at); };
    auto value = [&](uint64_t at) { return ndr::value_code(uint32_t(index_at(at))); };
    p.background_index = uint32_t(index_at(view.background()));

    // Every node must be reached once, through the tiles lookups reach: the
    // backend writes each node's slots once (node_majorants raises them
    // over every parent, and leaves the others as they are)
    std::vector<uint32_t> reached[3] = { std::vector<uint32_t>(p.leaf_count),
                                         std::vector<uint32_t>(p.lower_count),
                                         std::vector<uint32_t>(p.upper_count) };
    std::vector<int32_t> origin[3] = { {}, std::vector<int32_t>(3 * size_t(p.lower_count)),
                                       std::vector<int32_t>(3 * size_t(p.upper_count)) };
    p.lower_entries.assign(size_t(p.lower_count) * layout::LOWER_TABLE_COUNT, 0);
    p.upper_entries.assign(size_t(p.upper_count) * layout::UPPER_TABLE_COUNT, 0);
    p.lower_parent.assign(p.lower_count, 0);

    // fn(dx, dy, dz, first voxel) for the 27 cells of 2^log2dim voxels
    // around (and at) the one whose first voxel is o
    auto cells_around = [](const int32_t o[3], uint32_t log2dim, auto &&fn) {
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) {
                    const int d[3] = { dx, dy, dz };
                    int32_t n[3];
                    for (int a = 0; a < 3; ++a)
                        n[a] = wrap_add(o[a], int64_t(d[a]) << log2dim);
                    fn(dx, dy, dz, n);
                }
    };
    // What covers the cell of `level` at ijk, as a code
    auto cover = [&](int level, const int32_t ijk[3]) -> int32_t {
        const TreeView::Found f = view.find(level, ijk);
        return f.node == 0 ? value(f.value) : int32_t(view.node_index(level, f.node));
    };
    // An internal node's entries, and its children's origins
    auto entries = [&](int level, uint64_t node, const int32_t o[3], int32_t *out) {
        for (uint32_t e = 0; e < view.level(level).table_count; ++e) {
            if (!view.child_bit(level, node, e)) {
                out[e] = value(view.entry(level, node, e));
                continue;
            }
            const uint64_t child = view.child(level, node, e);
            const uint32_t i = uint32_t(view.node_index(level - 1, child));
            out[e] = int32_t(i);
            ++reached[level - 1][i];
            if (level == 2) {
                view.entry_origin(2, o, e, &origin[1][3 * size_t(i)]);
                p.lower_parent[i] = uint32_t(view.node_index(2, node));
            }
        }
    };
    for (uint32_t t : view.tiles()) {
        int32_t o[3];
        view.tile_origin(t, o);
        const uint64_t child = view.tile_child(t);
        p.tile_index.push_back(t);
        p.tile_origins.insert(p.tile_origins.end(), o, o + 3);
        if (child == 0) {
            p.tile_codes.push_back(value(view.tile_value(t)));
        } else {
            const uint32_t u = uint32_t(view.node_index(2, child));
            p.tile_codes.push_back(int32_t(u));
            ++reached[2][u];
            std::copy(o, o + 3, &origin[2][3 * size_t(u)]);
        }
        cells_around(o, layout::ROOT_TILE_LOG2, [&](int dx, int dy, int dz, const int32_t n[3]) {
            p.tile_around.push_back(cover(2, n));
            uint32_t covering;
            if ((dx || dy || dz) && !view.tile_of(n, covering)) {
                p.background_codes.push_back(p.tile_codes.back());
                p.background_layers.push_back(ndr::layer_of_direction(dx, dy, dz, true));
            }
        });
    }
    for (uint32_t u = 0; u < p.upper_count; ++u)
        if (reached[2][u] == 1)
            entries(2, view.node(2, u), &origin[2][3 * size_t(u)],
                    &p.upper_entries[size_t(u) * layout::UPPER_TABLE_COUNT]);
    for (uint32_t l = 0; l < p.lower_count; ++l)
        if (reached[1][l] == 1)
            entries(1, view.node(1, l), &origin[1][3 * size_t(l)],
                    &p.lower_entries[size_t(l) * layout::LOWER_TABLE_COUNT]);
    for (int level = 0; level < 3; ++level)
        for (uint32_t r : reached[level])
            if (r != 1)
                return refuse("a node that lookups reach not once but never or twice");

    // The node-sized cells around each internal node
    auto around = [&](int level, uint32_t count, std::vector<int32_t> &out) {
        const uint32_t log2dim = level == 1 ? 7 : 12;
        out.reserve(size_t(count) * 27);
        for (uint32_t i = 0; i < count; ++i)
            cells_around(&origin[level][3 * size_t(i)], log2dim,
                         [&](int, int, int, const int32_t n[3]) { out.push_back(cover(level, n)); });
    };
    around(1, p.lower_count, p.lower_around);
    around(2, p.upper_count, p.upper_around);

    // The entries whose ring is more than the tile values around them and
    // the values of the node-sized cells beyond the node that they touch
    // (rings()): children, tiles beside a child, and entries on the node's
    // faces that touch a node of the same level beyond them
    auto slow = [](const std::vector<int32_t> &entries, const std::vector<int32_t> &around,
                   uint32_t log2dim, std::vector<uint32_t> &out) {
        const int dim = 1 << log2dim;
        const uint32_t count = uint32_t(dim) * uint32_t(dim) * uint32_t(dim);
        for (size_t at = 0; at < entries.size(); ++at) {
            const size_t node = at / count;
            const uint32_t e = uint32_t(at % count);
            const int c[3] = { int(e >> (2 * log2dim)), int((e >> log2dim) & uint32_t(dim - 1)),
                               int(e & uint32_t(dim - 1)) };
            bool is_slow = entries[at] >= 0;
            for (int dx = -1; dx <= 1 && !is_slow; ++dx)
                for (int dy = -1; dy <= 1 && !is_slow; ++dy)
                    for (int dz = -1; dz <= 1 && !is_slow; ++dz) {
                        const int n[3] = { c[0] + dx, c[1] + dy, c[2] + dz };
                        int side[3];
                        for (int a = 0; a < 3; ++a)
                            side[a] = n[a] < 0 ? -1 : n[a] >= dim ? 1 : 0;
                        if (side[0] == 0 && side[1] == 0 && side[2] == 0)
                            is_slow |= entries[node * count + ((uint32_t(n[0]) << (2 * log2dim)) |
                                                               (uint32_t(n[1]) << log2dim) |
                                                               uint32_t(n[2]))] >= 0;
                        else
                            is_slow |= around[node * 27 +
                                              ndr::direction_index(side[0], side[1], side[2])] >= 0;
                    }
            if (is_slow)
                out.push_back(uint32_t(at));
        }
    };
    slow(p.lower_entries, p.lower_around, layout::LOWER_LOG2_DIM, p.lower_slow);
    slow(p.upper_entries, p.upper_around, layout::UPPER_LOG2_DIM, p.upper_slow);
    p.lower_origins = std::move(origin[1]);
    p.upper_origins = std::move(origin[2]);
    return p;
}

} // namespace nanovdb_loader
