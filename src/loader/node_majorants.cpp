// src/loader/node_majorants.cpp -- node_majorants() (see majorants.h): one
// walk from the root tiles down the tree, bottom-up, each entry bounded with
// the ring of voxels its region's neighbours hold.
//
// The ring of a cell (an aligned cube of D^3 voxels: a leaf or lower tile
// D = 8, an upper tile or lower node 128, a root tile 4096) is read from its
// 26 neighbouring cells of the same size: whatever covers a neighbour (a
// node of that level, or a tile or the background, i.e. one value)
// contributes the layer of its voxels that touches the cell -- a face, an
// edge or a corner. A neighbour whose maximum cannot raise the bound is
// skipped without reading its voxels.

#include <nanovdb_loader/majorants.h>

#include "detail.h"
#include "value_codec.h"

#include <algorithm>
#include <cstring>
#include <iterator>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>
#include <unordered_map>

namespace nanovdb_loader {

namespace {

using namespace detail;

constexpr float kNone = -std::numeric_limits<float>::infinity();

/// Raises m to v; NaN never counts
inline void raise(float &m, float v) {
    if (v > m)
        m = v;
}

/// Lowers m to v; NaN never counts
inline void lower_to(float &m, float v) {
    if (v < m)
        m = v;
}

/// A bound that starts at v (NaN: at nothing)
inline float start(float v) { return std::isnan(v) ? kNone : v; }

/// Which layer of a region a neighbour touches, per axis
enum Layer : uint8_t { ALL, LOW, HIGH };

/// What covers a cell of some level: a node of that level, or one value
struct Cover {
    int level = -1;    ///< 0 leaf, 1 lower, 2 upper; -1: `value` covers it all
    uint64_t node = 0; ///< byte offset of the node
    float value = 0.f;
};

class Builder {
public:
    Builder(const ValidatedGrid &grid)
        : m_grid(grid), m_buf(grid.data()), m_s(grid.summary()),
          m_codec(m_s.grid_type), m_c(m_codec.constants()),
          m_root(uint64_t(m_s.root_word) * 4) {
        m_out.layout = nanovdb_drjit::MajorantTableLayout::make(
            m_s.node_begin, m_s.node_end, m_s.node_count, m_s.root_word, m_c.root_size,
            m_s.root_tile_count,
            m_codec.variable_leaf_size() ? layout::FPN_MIN_LEAF_SIZE : m_c.leaf_size);
        m_out.values.assign(m_out.layout.size, kNone);
        m_background = m_codec.tile_bound(m_buf + m_root + m_c.root_off_background);
    }

    NodeMajorants run() {
        index_root_tiles();
        unringed_bounds();
        for (const auto &[key, tile] : m_tiles) {
            int32_t o[3];
            layout::key_to_origin(key, o);
            const uint32_t t = uint32_t((tile - m_root - m_c.root_size) / m_c.root_tile_size);
            const int64_t child = load<int64_t>(m_buf + tile + layout::ROOT_TILE_OFF_CHILD);
            float e;
            if (child != 0) {
                e = upper(uint64_t(int64_t(m_root) + child), o);
            } else {
                e = start(m_codec.tile_bound(m_buf + tile + m_c.root_tile_off_value));
                ring(2, o, e);
            }
            raise(m_out.values[m_out.layout.tile_slot + t], e);
        }
        background();
        return std::move(m_out);
    }

private:
    // ---- The tree as a map from cells to what covers them ---------------------

    /// The first root tile of every key a coordinate can have (PNanoVDB's
    /// search returns the first match; keys with bits outside the three
    /// 20-bit fields match no coordinate)
    void index_root_tiles() {
        constexpr uint64_t unused = (uint64_t(1) << 20) | (uint64_t(1) << 41) |
                                    (uint64_t(3) << 62);
        for (uint64_t t = 0; t < m_s.root_tile_count; ++t) {
            const uint64_t tile = m_root + m_c.root_size + t * m_c.root_tile_size;
            const uint64_t key = load<uint64_t>(m_buf + tile + layout::ROOT_TILE_OFF_KEY);
            if (!(key & unused))
                m_tiles.emplace(key, tile); // keeps the first
        }
    }

    static uint64_t key_of(const int32_t ijk[3]) {
        return (uint64_t(uint32_t(ijk[0]) >> 12) << 42) |
               (uint64_t(uint32_t(ijk[1]) >> 12) << 21) | uint64_t(uint32_t(ijk[2]) >> 12);
    }

    bool child_bit(uint64_t node, uint64_t mask_off, uint32_t n) const {
        return (load<uint32_t>(m_buf + node + mask_off + 4 * (n >> 5)) >> (n & 31)) & 1u;
    }

    /// What covers the cell of `level` (0: 8^3, 1: 128^3, 2: 4096^3) that
    /// contains ijk: the traversal of PNanoVDB, stopped at that level
    Cover find(int level, const int32_t ijk[3]) {
        auto it = m_tiles.find(key_of(ijk));
        if (it == m_tiles.end())
            return { -1, 0, m_background };
        const uint64_t tile = it->second;
        const int64_t child = load<int64_t>(m_buf + tile + layout::ROOT_TILE_OFF_CHILD);
        if (child == 0)
            return { -1, 0, m_codec.tile_bound(m_buf + tile + m_c.root_tile_off_value) };
        const uint64_t up = uint64_t(int64_t(m_root) + child);
        if (level == 2)
            return { 2, up, 0.f };
        const uint32_t nu = ((uint32_t(ijk[0]) & 4095u) >> 7) << 10 |
                            ((uint32_t(ijk[1]) & 4095u) >> 7) << 5 |
                            ((uint32_t(ijk[2]) & 4095u) >> 7);
        const uint64_t eu = up + m_c.upper_off_table + uint64_t(nu) * m_c.table_stride;
        if (!child_bit(up, layout::UPPER_OFF_CHILD_MASK, nu))
            return { -1, 0, m_codec.tile_bound(m_buf + eu) };
        const uint64_t lo = uint64_t(int64_t(up) + load<int64_t>(m_buf + eu));
        if (level == 1)
            return { 1, lo, 0.f };
        const uint32_t nl = ((uint32_t(ijk[0]) & 127u) >> 3) << 8 |
                            ((uint32_t(ijk[1]) & 127u) >> 3) << 4 |
                            ((uint32_t(ijk[2]) & 127u) >> 3);
        const uint64_t el = lo + m_c.lower_off_table + uint64_t(nl) * m_c.table_stride;
        if (!child_bit(lo, layout::LOWER_OFF_CHILD_MASK, nl))
            return { -1, 0, m_codec.tile_bound(m_buf + el) };
        return { 0, uint64_t(int64_t(lo) + load<int64_t>(m_buf + el)), 0.f };
    }

    // ---- Maxima of regions and of their layers ----------------------------------

    size_t leaf_index(uint64_t node) const {
        return size_t(m_grid.leaf_containing(node));
    }
    size_t lower_index(uint64_t node) const {
        return size_t((node - m_s.node_begin[1]) / m_c.lower_size);
    }
    size_t upper_index(uint64_t node) const {
        return size_t((node - m_s.node_begin[2]) / m_c.upper_size);
    }

    /// The min and max of each node's values, without ring: the max lets a
    /// neighbour be skipped, the min goes into the table (m). Leaves: from
    /// validation; lower, then upper nodes: their entries (every node of the
    /// arrays, reached or not).
    void unringed_bounds() {
        auto pass = [&](uint32_t count, uint64_t begin, uint64_t size, uint64_t mask_off,
                        uint64_t table_off, uint32_t entries, auto child_range,
                        std::vector<float> &mins, std::vector<float> &maxs) {
            mins.assign(count, std::numeric_limits<float>::infinity());
            maxs.assign(count, kNone);
            for (uint32_t i = 0; i < count; ++i) {
                const uint64_t node = begin + uint64_t(i) * size;
                for (uint32_t n = 0; n < entries; ++n) {
                    const uint64_t e = node + table_off + uint64_t(n) * m_c.table_stride;
                    float lo, hi;
                    if (child_bit(node, mask_off, n)) {
                        std::tie(lo, hi) =
                            child_range(uint64_t(int64_t(node) + load<int64_t>(m_buf + e)));
                    } else {
                        lo = hi = m_codec.tile_bound(m_buf + e);
                    }
                    lower_to(mins[i], lo);
                    raise(maxs[i], hi);
                }
            }
        };
        pass(m_s.node_count[1], m_s.node_begin[1], m_c.lower_size, layout::LOWER_OFF_CHILD_MASK,
             m_c.lower_off_table, layout::LOWER_TABLE_COUNT,
             [&](uint64_t leaf) {
                 const size_t i = leaf_index(leaf);
                 return std::make_pair(m_grid.leaf_min()[i], m_grid.leaf_max()[i]);
             },
             m_lower_min, m_lower_max);
        pass(m_s.node_count[2], m_s.node_begin[2], m_c.upper_size, layout::UPPER_OFF_CHILD_MASK,
             m_c.upper_off_table, layout::UPPER_TABLE_COUNT,
             [&](uint64_t lower) {
                 const size_t i = lower_index(lower);
                 return std::make_pair(m_lower_min[i], m_lower_max[i]);
             },
             m_upper_min, m_upper_max);
    }

    /// Raises m to the values of the layer `sel` of what `c` covers (per
    /// axis: all entries, the lowest or the highest); skips a node whose
    /// maximum cannot raise m
    void layer_max(const Cover &c, const Layer sel[3], float &m) const {
        if (c.level < 0) {
            raise(m, c.value);
            return;
        }
        uint32_t log2dim;
        float bound;
        if (c.level == 0) {
            log2dim = layout::LEAF_LOG2_DIM;
            bound = m_grid.leaf_max()[leaf_index(c.node)];
        } else if (c.level == 1) {
            log2dim = layout::LOWER_LOG2_DIM;
            bound = m_lower_max[lower_index(c.node)];
        } else {
            log2dim = layout::UPPER_LOG2_DIM;
            bound = m_upper_max[upper_index(c.node)];
        }
        if (!(bound > m))
            return;
        const uint32_t last = (1u << log2dim) - 1;
        uint32_t lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
            lo[a] = sel[a] == HIGH ? last : 0;
            hi[a] = sel[a] == LOW ? 0 : last;
        }
        for (uint32_t i = lo[0]; i <= hi[0]; ++i)
            for (uint32_t j = lo[1]; j <= hi[1]; ++j)
                for (uint32_t k = lo[2]; k <= hi[2]; ++k) {
                    const uint32_t n = (i << (2 * log2dim)) | (j << log2dim) | k;
                    if (c.level == 0) {
                        raise(m, m_codec.leaf_bound(m_buf + c.node, n));
                        continue;
                    }
                    const bool upper = c.level == 2;
                    const uint64_t e = c.node + (upper ? m_c.upper_off_table : m_c.lower_off_table) +
                                       uint64_t(n) * m_c.table_stride;
                    if (!child_bit(c.node, upper ? layout::UPPER_OFF_CHILD_MASK
                                                 : layout::LOWER_OFF_CHILD_MASK, n)) {
                        raise(m, m_codec.tile_bound(m_buf + e));
                        continue;
                    }
                    const Cover below{ c.level - 1,
                                       uint64_t(int64_t(c.node) + load<int64_t>(m_buf + e)), 0.f };
                    layer_max(below, sel, m);
                }
    }

    /// Calls fn(neighbour's first voxel, layers) for the 26 neighbours of the
    /// cell of 2^log2dim voxels whose first voxel is `o`; `layers` are the
    /// neighbour's layers that touch the cell (`ours`: the cell's own layers
    /// that touch the neighbour)
    template <typename Fn>
    static void for_each_neighbour(const int32_t o[3], uint32_t log2dim, bool ours, Fn &&fn) {
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) {
                    if (!dx && !dy && !dz)
                        continue;
                    const int d[3] = { dx, dy, dz };
                    int32_t n[3];
                    Layer sel[3];
                    for (int a = 0; a < 3; ++a) {
                        n[a] = wrap_add(o[a], int64_t(d[a]) * (int64_t(1) << log2dim));
                        sel[a] = d[a] == 0 ? ALL : ((d[a] > 0) != ours) ? LOW : HIGH;
                    }
                    fn(n, sel);
                }
    }

    /// Raises m to the ring of the cell of `level` (0: 8^3, 1: 128^3,
    /// 2: 4096^3) whose first voxel is `o`: the layers of its 26 neighbours
    /// that touch it
    void ring(int level, const int32_t o[3], float &m) {
        const uint32_t log2dim = level == 0 ? 3 : level == 1 ? 7 : 12;
        for_each_neighbour(o, log2dim, false, [&](const int32_t n[3], const Layer sel[3]) {
            layer_max(find(level, n), sel, m);
        });
    }

    // ---- Bottom-up: entries, then their node --------------------------------------

    /// An upper node at byte `node`, first voxel `o`: returns its M
    float upper(uint64_t node, const int32_t o[3]) {
        float M = kNone, R = kNone;
        for (uint32_t n = 0; n < layout::UPPER_TABLE_COUNT; ++n) {
            const int32_t eo[3] = { wrap_add(o[0], int64_t(n >> 10) << 7),
                                    wrap_add(o[1], int64_t((n >> 5) & 31) << 7),
                                    wrap_add(o[2], int64_t(n & 31) << 7) };
            const uint64_t e = node + m_c.upper_off_table + uint64_t(n) * m_c.table_stride;
            if (child_bit(node, layout::UPPER_OFF_CHILD_MASK, n)) {
                raise(M, lower(uint64_t(int64_t(node) + load<int64_t>(m_buf + e)), eo));
                continue;
            }
            const float v = start(m_codec.tile_bound(m_buf + e));
            float r = v;
            ring(1, eo, r);
            raise(M, r);
            if (r > v)
                raise(R, r);
        }
        const size_t i = upper_index(node);
        store(m_out.layout.upper_slot + nanovdb_drjit::UPPER_SLOTS * uint32_t(i), M, R,
              m_upper_min[i]);
        return M;
    }

    /// A lower node at byte `node`, first voxel `o`: returns its M
    float lower(uint64_t node, const int32_t o[3]) {
        float M = kNone, R = kNone;
        float brick[nanovdb_drjit::LOWER_BRICK_COUNT], brick_lo[nanovdb_drjit::LOWER_BRICK_COUNT];
        std::fill(std::begin(brick), std::end(brick), kNone);
        std::fill(std::begin(brick_lo), std::end(brick_lo), std::numeric_limits<float>::infinity());
        for (uint32_t n = 0; n < layout::LOWER_TABLE_COUNT; ++n) {
            const int32_t eo[3] = { wrap_add(o[0], int64_t(n >> 8) << 3),
                                    wrap_add(o[1], int64_t((n >> 4) & 15) << 3),
                                    wrap_add(o[2], int64_t(n & 15) << 3) };
            const uint64_t e = node + m_c.lower_off_table + uint64_t(n) * m_c.table_stride;
            float r, lo;
            if (child_bit(node, layout::LOWER_OFF_CHILD_MASK, n)) {
                const uint64_t leaf = uint64_t(int64_t(node) + load<int64_t>(m_buf + e));
                const size_t i = leaf_index(leaf);
                r = m_grid.leaf_max()[i];
                lo = m_grid.leaf_min()[i];
                ring(0, eo, r);
                raise(m_out.values[m_out.layout.leaf_slot(uint32_t(leaf / 4))], r);
            } else {
                const float v = start(m_codec.tile_bound(m_buf + e));
                r = lo = v;
                ring(0, eo, r);
                if (r > v)
                    raise(R, r);
            }
            raise(M, r);
            const uint32_t b = nanovdb_drjit::brick_of(uint32_t(n >> 8) << 3,
                                                       uint32_t((n >> 4) & 15) << 3,
                                                       uint32_t(n & 15) << 3);
            raise(brick[b], r);
            lower_to(brick_lo[b], lo);
        }
        const size_t i = lower_index(node);
        const uint32_t slot = m_out.layout.lower_slot + nanovdb_drjit::LOWER_SLOTS * uint32_t(i);
        store(slot, M, R, m_lower_min[i]);
        for (uint32_t b = 0; b < nanovdb_drjit::LOWER_BRICK_COUNT; ++b)
            raise(m_out.values[slot + nanovdb_drjit::LOWER_BRICK_M_SLOT + b], brick[b]);
        // The bricks' m, 8-bit fractions of their (final) M, four to a slot
        for (uint32_t w = 0; w < nanovdb_drjit::LOWER_BRICK_COUNT / 4; ++w) {
            uint32_t bits = 0;
            for (uint32_t k = 0; k < 4; ++k) {
                const uint32_t b = 4 * w + k;
                bits |= nanovdb_drjit::brick_fraction(
                            m_out.values[slot + nanovdb_drjit::LOWER_BRICK_M_SLOT + b], brick_lo[b])
                        << (8 * k);
            }
            std::memcpy(&m_out.values[slot + nanovdb_drjit::LOWER_BRICK_FRACTION_SLOT + w], &bits, 4);
        }
        return M;
    }

    /// An internal node's M, R (raised over every parent that reaches it) and m
    void store(uint32_t slot, float M, float R, float m) {
        raise(m_out.values[slot], M);
        raise(m_out.values[slot + 1], R);
        m_out.values[slot + 2] = m;
    }

    /// The background's slot: the background, and the layers of the covered
    /// blocks that touch uncovered ones
    void background() {
        float m = start(m_background);
        for (const auto &[key, tile] : m_tiles) {
            int32_t o[3];
            layout::key_to_origin(key, o);
            const int64_t child = load<int64_t>(m_buf + tile + layout::ROOT_TILE_OFF_CHILD);
            const Cover self = child != 0
                                   ? Cover{ 2, uint64_t(int64_t(m_root) + child), 0.f }
                                   : Cover{ -1, 0, m_codec.tile_bound(m_buf + tile + m_c.root_tile_off_value) };
            for_each_neighbour(o, layout::ROOT_TILE_LOG2, true,
                               [&](const int32_t n[3], const Layer sel[3]) {
                                   if (m_tiles.count(key_of(n)) == 0)
                                       layer_max(self, sel, m);
                               });
        }
        m_out.values[m_out.layout.background_slot] = m;
    }

    const ValidatedGrid &m_grid;
    const uint8_t *m_buf;
    const GridSummary &m_s;
    const detail::ValueCodec m_codec;
    const layout::GridTypeConstants &m_c;
    const uint64_t m_root;
    float m_background = 0.f;
    std::unordered_map<uint64_t, uint64_t> m_tiles; ///< key -> first tile's byte offset
    std::vector<float> m_lower_min, m_lower_max, m_upper_min, m_upper_max; ///< no ring
    NodeMajorants m_out;
};

} // namespace

NodeMajorants node_majorants(const ValidatedGrid &grid) { return Builder(grid).run(); }

} // namespace nanovdb_loader
