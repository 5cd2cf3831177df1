// The active tiles of a grid (nanovdb_loader/active_tiles.h), by a walk of
// its tree from the root tiles lookups reach (tree_view.h).

#include <nanovdb_loader/active_tiles.h>

#include "tree_view.h"

#include <algorithm>

namespace nanovdb_loader {

using namespace detail;

std::vector<ActiveTile> active_tiles(const ValidatedGrid &grid) {
    const TreeView view(grid);
    const uint8_t *buf = view.data();
    std::vector<ActiveTile> out;
    auto add = [&](const int32_t origin[3], uint32_t log2dim, uint64_t value_byte) {
        out.push_back({ { origin[0], origin[1], origin[2] }, log2dim, uint32_t(value_byte / 4) });
    };
    // The entries of an internal node of `level` whose value bit is set and
    // child bit clear, 32 at a time
    auto node_tiles = [&](int level, uint64_t node, const int32_t origin[3], auto &&child) {
        const NodeLevel &l = view.level(level);
        const uint32_t value_mask =
            level == 2 ? layout::UPPER_OFF_VALUE_MASK : layout::LOWER_OFF_VALUE_MASK;
        for (uint32_t w = 0; w < l.table_count / 32; ++w) {
            const uint32_t values = load<uint32_t>(buf + node + value_mask + 4 * w),
                           children = load<uint32_t>(buf + node + l.mask_off + 4 * w);
            for (uint32_t bits = children; bits; bits &= bits - 1) {
                const uint32_t e = 32 * w + uint32_t(__builtin_ctz(bits));
                int32_t o[3];
                view.entry_origin(level, origin, e, o);
                child(view.child(level, node, e), o);
            }
            for (uint32_t bits = values & ~children; bits; bits &= bits - 1) {
                const uint32_t e = 32 * w + uint32_t(__builtin_ctz(bits));
                int32_t o[3];
                view.entry_origin(level, origin, e, o);
                add(o, l.log2entry, view.entry(level, node, e));
            }
        }
    };
    for (uint32_t t : view.tiles()) {
        int32_t origin[3];
        view.tile_origin(t, origin);
        const uint64_t upper = view.tile_child(t);
        if (upper == 0) {
            if (load<uint32_t>(buf + view.tile(t) + layout::ROOT_TILE_OFF_STATE) != 0)
                add(origin, 12, view.tile_value(t));
            continue;
        }
        node_tiles(2, upper, origin, [&](uint64_t lower, const int32_t o[3]) {
            node_tiles(1, lower, o, [](uint64_t, const int32_t *) {});
        });
    }
    std::sort(out.begin(), out.end(), [](const ActiveTile &a, const ActiveTile &b) {
        return a.value_word < b.value_word;
    });
    return out;
}

} // namespace nanovdb_loader
