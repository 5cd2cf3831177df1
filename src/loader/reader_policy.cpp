// src/loader/reader_policy.cpp -- plan_readers() (see reader_policy.h).

#include <nanovdb_loader/reader_policy.h>

#include "detail.h"
#include "tree_view.h"

#include <algorithm>
#include <climits>

namespace nanovdb_loader {

using namespace detail;

uint64_t max_root_index_entries(uint64_t grid_bytes) {
    return std::max<uint64_t>(64, grid_bytes / 1024);
}

bool has_compact_offsets(const ValidatedGrid &grid) {
    if (grid.bytes() >= (uint64_t(1) << 32))
        return false;
    const GridSummary &s = grid.summary();
    // End of the previous array, in bytes
    uint64_t end = uint64_t(s.root_word) * 4 + 4;
    for (int level : { 2, 1, 0 }) {
        if (s.node_count[level] == 0)
            continue;
        if (s.node_begin[level] < end)
            return false;
        end = s.node_end[level];
    }
    return true;
}

bool build_root_index(const ValidatedGrid &grid, uint64_t max_entries, ReaderPlan &plan) {
    // The tiles lookups reach, one per key (the first, as the linear search
    // finds it); validation refused keys that no coordinate has, so each
    // key is a block and each block has at most one tile
    const TreeView view(grid);
    auto tile_block = [&](uint32_t t, int32_t block[3]) {
        layout::key_to_block(view.tile_key(t), block);
    };
    int64_t lo[3] = { INT64_MAX, INT64_MAX, INT64_MAX },
            hi[3] = { INT64_MIN, INT64_MIN, INT64_MIN };
    for (uint32_t t : view.tiles()) {
        int32_t b[3];
        tile_block(t, b);
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min<int64_t>(lo[k], b[k]);
            hi[k] = std::max<int64_t>(hi[k], b[k]);
        }
    }
    if (view.tiles().empty())
        for (int k = 0; k < 3; ++k)
            lo[k] = hi[k] = 0;
    uint64_t entries = 1;
    for (int k = 0; k < 3; ++k)
        entries *= uint64_t(hi[k] - lo[k] + 1);
    if (entries > max_entries)
        return false;

    plan.root_table.assign(entries, 0u);
    for (int k = 0; k < 3; ++k) {
        plan.block_min[k] = int32_t(lo[k]);
        plan.block_dims[k] = view.tiles().empty() ? 0 : int32_t(hi[k] - lo[k] + 1);
    }
    for (uint32_t t : view.tiles()) {
        int32_t b[3];
        tile_block(t, b);
        const uint64_t i = uint64_t(((b[0] - lo[0]) * plan.block_dims[1] + (b[1] - lo[1])) *
                                        plan.block_dims[2] + (b[2] - lo[2]));
        plan.root_table[i] = uint32_t(view.tile(t) / 4);
    }
    return true;
}

ReaderPlan plan_readers(const ValidatedGrid &grid) {
    ReaderPlan plan;
    plan.root_word = grid.summary().root_word;
    plan.compact_offsets = has_compact_offsets(grid);
    plan.root_indexed = build_root_index(grid, max_root_index_entries(grid.bytes()), plan);
    if (!plan.root_indexed)
        plan.root_table.clear();
    return plan;
}

} // namespace nanovdb_loader
