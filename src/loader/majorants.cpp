// src/loader/majorants.cpp -- max_in_box() (see majorants.h): a walk from the
// root tiles down through the nodes whose region meets the box.

#include <nanovdb_loader/majorants.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <limits>

namespace nanovdb_loader {

namespace {

using namespace detail;

/// Entries [first, last] per axis of a node whose first voxel is `origin`,
/// with 2^log2dim entries per axis of 2^log2entry voxels each, that meet
/// `box`; false if none
bool entry_range(const int64_t origin[3], uint32_t log2dim, uint32_t log2entry,
                 const IndexBox &box, int64_t first[3], int64_t last[3]) {
    const int64_t span = int64_t(1) << (log2dim + log2entry);
    for (int a = 0; a < 3; ++a) {
        const int64_t lo = std::max<int64_t>(box.lo[a], origin[a]),
                      hi = std::min<int64_t>(box.hi[a], origin[a] + span - 1);
        if (lo > hi)
            return false;
        first[a] = (lo - origin[a]) >> log2entry;
        last[a] = (hi - origin[a]) >> log2entry;
    }
    return true;
}

class BoxMax {
public:
    /// per_channel: also the largest value of each channel (Vec3f)
    BoxMax(const ValidatedGrid &grid, const IndexBox &box, bool per_channel = false)
        : m_grid(grid), m_view(grid), m_box(box), m_buf(grid.data()),
          m_codec(grid.summary().grid_type, &grid.index_values()),
          m_per_channel(per_channel && m_codec.channels() > 1) {}

    /// The largest value of each channel (valid after run(); -Inf where none)
    float channel_max[3] = { -std::numeric_limits<float>::infinity(),
                             -std::numeric_limits<float>::infinity(),
                             -std::numeric_limits<float>::infinity() };

    float run() {
        uint64_t covered = 0; // distinct root tiles whose block meets the box
        for (uint32_t t : m_view.tiles()) {
            int32_t o[3];
            m_view.tile_origin(t, o);
            const int64_t origin[3] = { o[0], o[1], o[2] };
            int64_t first[3], last[3];
            if (!entry_range(origin, 0, layout::ROOT_TILE_LOG2, m_box, first, last))
                continue;
            ++covered;
            const uint64_t child = m_view.tile_child(t);
            if (child == 0)
                include_tile(m_view.tile_value(t));
            else
                internal(2, child, origin);
        }
        // Blocks of 4096^3 the box meets; where a root tile covers fewer, a
        // lookup in the box can fall through to the background
        uint64_t blocks = 1;
        for (int a = 0; a < 3; ++a)
            blocks *= uint64_t((int64_t(m_box.hi[a]) >> layout::ROOT_TILE_LOG2) -
                               (int64_t(m_box.lo[a]) >> layout::ROOT_TILE_LOG2) + 1);
        if (covered < blocks)
            include_tile(m_view.background());
        return m_any ? m_max : std::numeric_limits<float>::quiet_NaN();
    }

private:
    void include(float v) {
        if (std::isnan(v))
            return;
        m_max = m_any ? std::max(m_max, v) : v;
        m_any = true;
    }
    /// A value of `channels` floats
    void include_value(const float *v) {
        include(m_codec.bound(v));
        if (m_per_channel)
            for (int k = 0; k < 3; ++k)
                if (!std::isnan(v[k]))
                    channel_max[k] = std::max(channel_max[k], v[k]);
    }
    /// The tile value at byte `at`
    void include_tile(uint64_t at) {
        float v[3] = { 0.f, 0.f, 0.f };
        m_codec.tile(m_buf + at, v);
        include_value(v);
    }

    /// An upper (level 2) or lower (level 1) node at byte `node`
    void internal(int level, uint64_t node, const int64_t origin[3]) {
        const NodeLevel &l = m_view.level(level);
        int64_t first[3], last[3];
        if (!entry_range(origin, l.log2dim, l.log2entry, m_box, first, last))
            return;
        for (int64_t i = first[0]; i <= last[0]; ++i)
            for (int64_t j = first[1]; j <= last[1]; ++j)
                for (int64_t k = first[2]; k <= last[2]; ++k) {
                    const uint32_t e = uint32_t((i << (2 * l.log2dim)) | (j << l.log2dim) | k);
                    if (!m_view.child_bit(level, node, e)) {
                        include_tile(m_view.entry(level, node, e));
                        continue;
                    }
                    const int64_t sub[3] = { origin[0] + (i << l.log2entry),
                                             origin[1] + (j << l.log2entry),
                                             origin[2] + (k << l.log2entry) };
                    if (level == 2)
                        internal(1, m_view.child(level, node, e), sub);
                    else
                        leaf(m_view.child(level, node, e), sub);
                }
    }

    void leaf(uint64_t node, const int64_t origin[3]) {
        int64_t first[3], last[3];
        if (!entry_range(origin, layout::LEAF_LOG2_DIM, 0, m_box, first, last))
            return;
        const bool whole = first[0] == 0 && first[1] == 0 && first[2] == 0 && last[0] == 7 &&
                           last[1] == 7 && last[2] == 7;
        if (whole && !m_per_channel) {
            include(m_grid.leaf_max()[size_t(m_view.node_index(0, node))]);
            return;
        }
        for (int64_t i = first[0]; i <= last[0]; ++i)
            for (int64_t j = first[1]; j <= last[1]; ++j)
                for (int64_t k = first[2]; k <= last[2]; ++k) {
                    float v[3] = { 0.f, 0.f, 0.f };
                    m_codec.leaf_value(m_buf + node, uint32_t((i << 6) | (j << 3) | k), v);
                    include_value(v);
                }
    }

    const ValidatedGrid &m_grid;
    const TreeView m_view;
    const IndexBox m_box;
    const uint8_t *m_buf;
    const detail::ValueCodec m_codec;
    const bool m_per_channel;
    float m_max = 0.f;
    bool m_any = false;
};

} // namespace

IndexBox lookup_box(const GridSummary &s, int ring) {
    IndexBox box;
    for (int a = 0; a < 3; ++a) {
        box.lo[a] = s.empty ? 0 : s.bbox_min[a];
        box.hi[a] = s.empty ? 0 : s.bbox_max[a];
    }
    return lookup_box(box, ring);
}

IndexBox lookup_box(IndexBox box, int ring) {
    for (int a = 0; a < 3; ++a) {
        if (ring <= 0)
            continue;
        if (int64_t(box.lo[a]) - ring < INT32_MIN || int64_t(box.hi[a]) + ring > INT32_MAX) {
            box.lo[a] = INT32_MIN; // the ring wraps around: all of the axis
            box.hi[a] = INT32_MAX;
        } else {
            box.lo[a] -= ring;
            box.hi[a] += ring;
        }
    }
    return box;
}

float max_in_box(const ValidatedGrid &grid, const IndexBox &box) {
    return BoxMax(grid, box).run();
}

std::array<float, 3> max_in_box_per_channel(const ValidatedGrid &grid, const IndexBox &box) {
    BoxMax m(grid, box, true);
    const float all = m.run();
    if (detail::ValueCodec(grid.summary().grid_type, &grid.index_values()).channels() == 1)
        return { all, all, all };
    return { m.channel_max[0], m.channel_max[1], m.channel_max[2] };
}

} // namespace nanovdb_loader
