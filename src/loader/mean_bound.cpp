// src/loader/mean_bound.cpp -- mean_bound() (see majorants.h): how much the
// per-node majorants can save, as the mean over a box of the bound of the
// majorant walk's finest cell at each voxel, found top down from the root
// tiles as the walk finds it (nodes and bricks of one value whole).

#include <nanovdb_loader/majorants.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"

#include <algorithm>
#include <cstring>

namespace nanovdb_loader {

namespace {

using namespace detail;

/// The walk's finest cells over the box, top down
class MeanBound {
public:
    MeanBound(const ValidatedGrid &grid, const NodeMajorants &maj, const IndexBox &box,
              float clamp)
        : m_view(grid), m_buf(grid.data()), m_codec(grid.summary().grid_type, &grid.index_values()), m_t(maj.layout),
          m_v(maj.values), m_box(box), m_clamp(clamp) {}

    double run() {
        double covered = 0.0;
        for (uint32_t t : m_view.tiles()) {
            int32_t o[3];
            m_view.tile_origin(t, o);
            const double vol = overlap(o, layout::ROOT_TILE_LOG2);
            if (vol == 0.0)
                continue;
            covered += vol;
            const uint64_t child = m_view.tile_child(t);
            if (child == 0)
                add(m_v[m_t.tile_slot + t], vol);
            else
                upper(child, o);
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
        const uint32_t slot =
            m_t.upper_slot + nanovdb_drjit::UPPER_SLOTS * uint32_t(m_view.node_index(2, node));
        if (uniform(m_v[slot], m_v[slot + 2])) {
            add(m_v[slot], overlap(o, layout::ROOT_TILE_LOG2));
            return;
        }
        for (uint32_t n = 0; n < layout::UPPER_TABLE_COUNT; ++n) {
            int32_t eo[3];
            m_view.entry_origin(2, o, n, eo);
            const double vol = overlap(eo, layout::UPPER_ENTRY_LOG2);
            if (vol == 0.0)
                continue;
            if (m_view.child_bit(2, node, n))
                lower(m_view.child(2, node, n), eo);
            else
                add(std::max(m_codec.tile_bound(m_buf + m_view.entry(2, node, n)), m_v[slot + 1]), vol);
        }
    }

    void lower(uint64_t node, const int32_t o[3]) {
        const uint32_t slot =
            m_t.lower_slot + nanovdb_drjit::LOWER_SLOTS * uint32_t(m_view.node_index(1, node));
        const float M = m_v[slot], m = m_v[slot + 2];
        if (uniform(M, m)) {
            add(M, overlap(o, layout::UPPER_ENTRY_LOG2));
            return;
        }
        for (uint32_t n = 0; n < layout::LOWER_TABLE_COUNT; ++n) {
            const uint32_t i = n >> 8, j = (n >> 4) & 15, k = n & 15;
            int32_t eo[3];
            m_view.entry_origin(1, o, n, eo);
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
            std::memcpy(&fractions, &m_v[slot + nanovdb_drjit::LOWER_ENTRY_FRACTION_SLOT + n / 4], 4);
            add(nanovdb_drjit::child_bound(brick, (fractions >> (8 * (n % 4))) & 255u), vol);
        }
    }

    const TreeView m_view;
    const uint8_t *m_buf;
    const detail::ValueCodec m_codec;
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
