// src/loader/mean_bound.cpp -- mean_bound() (see majorants.h): how much the
// per-node majorants can save, as the mean over a box of the bound of the
// majorant walk's finest cell at each voxel, found top down from the root
// tiles as the walk finds it (nodes and bricks of one value whole).

#include <nanovdb_loader/majorants.h>

#include "detail.h"
#include "value_codec.h"

#include <algorithm>
#include <cstring>
#include <unordered_set>

namespace nanovdb_loader {

namespace {

using namespace detail;

/// The walk's finest cells over the box, top down
class MeanBound {
public:
    MeanBound(const ValidatedGrid &grid, const NodeMajorants &maj, const IndexBox &box,
              float clamp)
        : m_grid(grid), m_buf(grid.data()), m_s(grid.summary()),
          m_codec(m_s.grid_type), m_c(m_codec.constants()), m_t(maj.layout),
          m_v(maj.values), m_box(box), m_clamp(clamp) {}

    double run() {
        const uint64_t root = uint64_t(m_s.root_word) * 4;
        std::unordered_set<uint64_t> seen;
        double covered = 0.0;
        for (uint32_t t = 0; t < m_s.root_tile_count; ++t) {
            const uint64_t tile = root + m_c.root_size + uint64_t(t) * m_c.root_tile_size;
            const uint64_t key = load<uint64_t>(m_buf + tile + layout::ROOT_TILE_OFF_KEY);
            constexpr uint64_t unused = (uint64_t(1) << 20) | (uint64_t(1) << 41) |
                                        (uint64_t(3) << 62);
            if ((key & unused) || !seen.insert(key).second)
                continue;
            int32_t o[3];
            layout::key_to_origin(key, o);
            const double vol = overlap(o, layout::ROOT_TILE_LOG2);
            if (vol == 0.0)
                continue;
            covered += vol;
            const int64_t child = load<int64_t>(m_buf + tile + layout::ROOT_TILE_OFF_CHILD);
            if (child == 0)
                add(m_v[m_t.tile_slot + t], vol);
            else
                upper(uint64_t(int64_t(root) + child), o);
        }
        add(m_v[m_t.background_slot], box_volume() - covered);
        return m_sum / box_volume();
    }

private:
    double box_volume() const {
        double v = 1.0;
        for (int a = 0; a < 3; ++a)
            v *= double(int64_t(m_box.hi[a]) - m_box.lo[a] + 1);
        return v;
    }

    /// Voxels of the cell of 2^log2dim at o inside the box
    double overlap(const int32_t o[3], uint32_t log2dim) const {
        double v = 1.0;
        for (int a = 0; a < 3; ++a) {
            const int64_t lo = std::max<int64_t>(o[a], m_box.lo[a]),
                          hi = std::min<int64_t>(int64_t(o[a]) + (int64_t(1) << log2dim) - 1,
                                                 m_box.hi[a]);
            if (lo > hi)
                return 0.0;
            v *= double(hi - lo + 1);
        }
        return v;
    }

    void add(float bound, double vol) {
        if (vol > 0.0)
            m_sum += double(std::min(std::max(bound, 0.f), m_clamp)) * vol;
    }

    static bool uniform(float M, float m) { return !(M - m > 0.f); }

    void upper(uint64_t node, const int32_t o[3]) {
        const uint32_t slot = m_t.upper_slot + nanovdb_drjit::UPPER_SLOTS *
                                                   uint32_t((node - m_s.node_begin[2]) / m_c.upper_size);
        if (uniform(m_v[slot], m_v[slot + 2])) {
            add(m_v[slot], overlap(o, layout::ROOT_TILE_LOG2));
            return;
        }
        for (uint32_t n = 0; n < layout::UPPER_TABLE_COUNT; ++n) {
            const int32_t eo[3] = { wrap_add(o[0], int64_t(n >> 10) << 7),
                                    wrap_add(o[1], int64_t((n >> 5) & 31) << 7),
                                    wrap_add(o[2], int64_t(n & 31) << 7) };
            const double vol = overlap(eo, layout::UPPER_ENTRY_LOG2);
            if (vol == 0.0)
                continue;
            const uint64_t e = node + m_c.upper_off_table + uint64_t(n) * m_c.table_stride;
            if ((load<uint32_t>(m_buf + node + layout::UPPER_OFF_CHILD_MASK + 4 * (n >> 5)) >>
                 (n & 31)) & 1u)
                lower(uint64_t(int64_t(node) + load<int64_t>(m_buf + e)), eo);
            else
                add(std::max(m_codec.tile_bound(m_buf + e), m_v[slot + 1]), vol);
        }
    }

    void lower(uint64_t node, const int32_t o[3]) {
        const uint32_t slot = m_t.lower_slot + nanovdb_drjit::LOWER_SLOTS *
                                                   uint32_t((node - m_s.node_begin[1]) / m_c.lower_size);
        const float M = m_v[slot], R = m_v[slot + 1], m = m_v[slot + 2];
        if (uniform(M, m)) {
            add(M, overlap(o, layout::UPPER_ENTRY_LOG2));
            return;
        }
        for (uint32_t n = 0; n < layout::LOWER_TABLE_COUNT; ++n) {
            const uint32_t i = n >> 8, j = (n >> 4) & 15, k = n & 15;
            const int32_t eo[3] = { wrap_add(o[0], int64_t(i) << 3),
                                    wrap_add(o[1], int64_t(j) << 3),
                                    wrap_add(o[2], int64_t(k) << 3) };
            const double vol = overlap(eo, layout::LOWER_ENTRY_LOG2);
            if (vol == 0.0)
                continue;
            const uint32_t b = nanovdb_drjit::brick_of(i << 3, j << 3, k << 3);
            const float brick = m_v[slot + nanovdb_drjit::LOWER_BRICK_M_SLOT + b];
            uint32_t fractions;
            std::memcpy(&fractions, &m_v[slot + nanovdb_drjit::LOWER_BRICK_FRACTION_SLOT + b / 4], 4);
            if (uniform(brick, nanovdb_drjit::brick_min(brick, (fractions >> (8 * (b % 4))) & 255u))) {
                add(brick, vol);
                continue;
            }
            const uint64_t e = node + m_c.lower_off_table + uint64_t(n) * m_c.table_stride;
            if ((load<uint32_t>(m_buf + node + layout::LOWER_OFF_CHILD_MASK + 4 * (n >> 5)) >>
                 (n & 31)) & 1u) {
                const uint64_t leaf = uint64_t(int64_t(node) + load<int64_t>(m_buf + e));
                add(m_v[m_t.leaf_slot(uint32_t(leaf / 4))], vol);
            } else {
                add(std::max(m_codec.tile_bound(m_buf + e), std::min(R, brick)), vol);
            }
        }
    }

    const ValidatedGrid &m_grid;
    const uint8_t *m_buf;
    const GridSummary &m_s;
    const detail::ValueCodec m_codec;
    const layout::GridTypeConstants &m_c;
    const nanovdb_drjit::MajorantTableLayout &m_t;
    const std::vector<float> &m_v;
    const IndexBox m_box;
    const float m_clamp;
    double m_sum = 0.0;
};

} // namespace

double mean_bound(const ValidatedGrid &grid, const NodeMajorants &majorants,
                  const IndexBox &box, float clamp) {
    return MeanBound(grid, majorants, box, clamp).run();
}

} // namespace nanovdb_loader
