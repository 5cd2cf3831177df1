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
#include "tree_view.h"
#include "value_codec.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <iterator>
#include <cmath>
#include <limits>
#include <thread>
#include <tuple>
#include <utility>

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

/// Moves m towards v: raises it (Max) or lowers it
template <bool Max> inline void extend(float &m, float v) {
    if constexpr (Max)
        raise(m, v);
    else
        lower_to(m, v);
}

/// What a region of the tree contributes to the controls of the cell that
/// holds it (majorant_table.h): the mean of its voxels' values (NaN as 0:
/// the value policy has replaced them) and the smallest value a lookup in
/// its ringed region can return
struct Control {
    double mean = 0.0;
    float lo = std::numeric_limits<float>::infinity();
};

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
    Builder(const ValidatedGrid &grid, int ring, unsigned threads)
        : m_threads(threads), m_grid(grid), m_view(grid), m_buf(grid.data()), m_codec(grid.summary().grid_type, &grid.index_values()),
          m_ring(uint32_t(std::clamp(ring, 1, 8))) {
        const GridSummary &s = grid.summary();
        const layout::GridTypeConstants &c = m_codec.constants();
        m_out.layout = nanovdb_drjit::MajorantTableLayout::make(
            s.node_begin, s.node_end, s.node_count, s.root_word, c.root_size, s.root_tile_count,
            m_codec.variable_leaf_size() ? layout::FPN_MIN_LEAF_SIZE : c.leaf_size);
        m_out.values.assign(m_out.layout.size, kNone);
        // The entries' 8-bit fractions are bits, raised byte by byte: from 0;
        // the controls too (a node no walk reaches keeps 0s)
        for (uint32_t i = 0; i < s.node_count[1]; ++i)
            std::fill_n(&m_out.values[m_out.layout.lower_slot + nanovdb_drjit::LOWER_SLOTS * i +
                                      nanovdb_drjit::LOWER_ENTRY_FRACTION_SLOT],
                        nanovdb_drjit::LOWER_SLOTS - nanovdb_drjit::LOWER_ENTRY_FRACTION_SLOT, 0.f);
        for (uint32_t i = 0; i < s.node_count[2]; ++i)
            m_out.values[m_out.layout.upper_slot + nanovdb_drjit::UPPER_SLOTS * i +
                         nanovdb_drjit::UPPER_CONTROL_SLOT] = 0.f;
        m_background = bound_at(m_view.background());
    }

    NodeMajorants run() {
        unringed_bounds();
        lower_nodes();
        for (uint32_t t : m_view.tiles()) { // a tile lookups never reach keeps -Inf
            int32_t o[3];
            m_view.tile_origin(t, o);
            m_out.tile_origins.insert(m_out.tile_origins.end(), o, o + 3);
            const uint64_t child = m_view.tile_child(t);
            float e;
            if (child != 0) {
                e = upper(child, o);
            } else {
                e = start(bound_at(m_view.tile_value(t)));
                ring(2, o, e);
            }
            raise(m_out.values[m_out.layout.tile_slot + t], e);
        }
        background();
        return std::move(m_out);
    }

private:
    /// Every lower node that lookups reach, bounded first and in parallel
    /// (each writes only its own slots and its leaves'), its M and control
    /// kept for upper(): the same table as one thread computes, bit for bit
    void lower_nodes() {
        struct Job {
            uint64_t node;
            int32_t o[3];
        };
        std::vector<Job> jobs;
        for (uint32_t t : m_view.tiles()) {
            const uint64_t upper_node = m_view.tile_child(t);
            if (upper_node == 0)
                continue;
            int32_t o[3];
            m_view.tile_origin(t, o);
            for (uint32_t n = 0; n < layout::UPPER_TABLE_COUNT; ++n)
                if (m_view.child_bit(2, upper_node, n)) {
                    Job j{ m_view.child(2, upper_node, n), {} };
                    m_view.entry_origin(2, o, n, j.o);
                    jobs.push_back(j);
                }
        }
        m_lower.assign(size_t(m_view.node_count(1)), {});
        std::atomic<size_t> next{ 0 };
        auto work = [&]() {
            Scratch scratch;
            for (size_t i; (i = next.fetch_add(1)) < jobs.size();)
                m_lower[index(1, jobs[i].node)] = lower(jobs[i].node, jobs[i].o, scratch);
        };
        // (by default, threads only where there is enough to share: 16
        // lower nodes are 64 K entries)
        const size_t threads =
            m_threads != 0 ? std::min<size_t>(m_threads, std::max<size_t>(jobs.size(), 1))
                           : std::min<size_t>(std::clamp(std::thread::hardware_concurrency(),
                                                         1u, 16u),
                                              jobs.size() / 16 + 1);
        std::vector<std::thread> pool;
        for (size_t k = 1; k < threads; ++k)
            pool.emplace_back(work);
        work();
        for (std::thread &th : pool)
            th.join();
    }

    /// The bound of the tile value at byte `at`
    float bound_at(uint64_t at) const { return m_codec.tile_bound(m_buf + at); }

    /// What covers the cell of `level` (0: 8^3, 1: 128^3, 2: 4096^3) that
    /// contains ijk: the traversal of PNanoVDB, stopped at that level
    Cover find(int level, const int32_t ijk[3]) const {
        const TreeView::Found f = m_view.find(level, ijk);
        if (f.node == 0)
            return { -1, 0, bound_at(f.value) };
        return { level, f.node, 0.f };
    }

    // ---- Maxima of regions and of their layers ----------------------------------

    size_t index(int level, uint64_t node) const { return size_t(m_view.node_index(level, node)); }

    /// The min and max of each node's values, without ring: the max lets a
    /// neighbour be skipped, the min goes into the table (m). Leaves: from
    /// validation; lower, then upper nodes: their entries (every node of the
    /// arrays, reached or not).
    void unringed_bounds() {
        auto pass = [&](int level, auto child_range, std::vector<float> &mins,
                        std::vector<float> &maxs) {
            const size_t count = size_t(m_view.node_count(level));
            mins.assign(count, std::numeric_limits<float>::infinity());
            maxs.assign(count, kNone);
            for (size_t i = 0; i < count; ++i) {
                const uint64_t node = m_view.node(level, i);
                for (uint32_t n = 0; n < m_view.level(level).table_count; ++n) {
                    float lo, hi;
                    if (m_view.child_bit(level, node, n))
                        std::tie(lo, hi) = child_range(index(level - 1, m_view.child(level, node, n)));
                    else
                        lo = hi = bound_at(m_view.entry(level, node, n));
                    lower_to(mins[i], lo);
                    raise(maxs[i], hi);
                }
            }
        };
        pass(1, [&](size_t leaf) {
                 return std::make_pair(m_grid.leaf_min()[leaf], m_grid.leaf_max()[leaf]);
             }, m_lower_min, m_lower_max);
        pass(2, [&](size_t lower) {
                 return std::make_pair(m_lower_min[lower], m_lower_max[lower]);
             }, m_upper_min, m_upper_max);
    }

    /// Raises (Max) or lowers m to the values of the layer `sel` of what `c`
    /// covers (per axis: all entries, the lowest or the highest); skips a
    /// node whose maximum (minimum) cannot move m
    template <bool Max = true>
    void layer_extreme(const Cover &c, const Layer sel[3], float &m) const {
        if (c.level < 0) {
            extend<Max>(m, c.value);
            return;
        }
        const size_t at = index(c.level, c.node);
        const float bound = Max ? (c.level == 0   ? m_grid.leaf_max()[at]
                                   : c.level == 1 ? m_lower_max[at]
                                                  : m_upper_max[at])
                                : (c.level == 0   ? m_grid.leaf_min()[at]
                                   : c.level == 1 ? m_lower_min[at]
                                                  : m_upper_min[at]);
        if (Max ? !(bound > m) : !(bound < m))
            return;
        // (constants, not m_view.level(): the loops below run for every
        // neighbour of every node, and known shifts make them cheaper)
        const uint32_t log2dim = c.level == 0   ? layout::LEAF_LOG2_DIM
                                 : c.level == 1 ? layout::LOWER_LOG2_DIM
                                                : layout::UPPER_LOG2_DIM,
                       last = (1u << log2dim) - 1;
        // A layer is m_ring voxels thick: that many leaf voxels, or the
        // first or last entry of an internal node (8 or more voxels wide)
        const uint32_t thick = c.level == 0 ? m_ring : 1;
        uint32_t lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
            lo[a] = sel[a] == HIGH ? last + 1 - thick : 0;
            hi[a] = sel[a] == LOW ? thick - 1 : last;
        }
        for (uint32_t i = lo[0]; i <= hi[0]; ++i)
            for (uint32_t j = lo[1]; j <= hi[1]; ++j)
                for (uint32_t k = lo[2]; k <= hi[2]; ++k) {
                    const uint32_t n = (i << (2 * log2dim)) | (j << log2dim) | k;
                    if (c.level == 0)
                        extend<Max>(m, m_codec.leaf_bound(m_buf + c.node, n));
                    else if (!m_view.child_bit(c.level, c.node, n))
                        extend<Max>(m, bound_at(m_view.entry(c.level, c.node, n)));
                    else
                        layer_extreme<Max>(Cover{ c.level - 1, m_view.child(c.level, c.node, n), 0.f },
                                           sel, m);
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

    /// Raises (Max) or lowers m to the ring of the cell of `level` (0: 8^3,
    /// 1: 128^3, 2: 4096^3) whose first voxel is `o`: the layers of its 26
    /// neighbours that touch it. `parent` (0: unknown): the node of level + 1
    /// that holds the cell; a neighbour in it is its entry there (what
    /// find() would reach from the root, without the search: most
    /// neighbours are, and the rebuild after an update (index_updates.h)
    /// runs this for every entry of every node)
    template <bool Max = true>
    void ring(int level, const int32_t o[3], float &m, uint64_t parent = 0) const {
        const uint32_t log2dim = level == 0 ? 3 : level == 1 ? 7 : 12;
        const uint32_t outside = ~((1u << (level == 0 ? 7 : 12)) - 1u); // (the parent's span)
        for_each_neighbour(o, log2dim, false, [&](const int32_t n[3], const Layer sel[3]) {
            if (parent != 0 && level < 2 &&
                ((uint32_t(n[0]) ^ uint32_t(o[0])) & outside) == 0 &&
                ((uint32_t(n[1]) ^ uint32_t(o[1])) & outside) == 0 &&
                ((uint32_t(n[2]) ^ uint32_t(o[2])) & outside) == 0) {
                const uint32_t e = m_view.entry_of(level + 1, n);
                const Cover c = m_view.child_bit(level + 1, parent, e)
                    ? Cover{ level, m_view.child(level + 1, parent, e), 0.f }
                    : Cover{ -1, 0, bound_at(m_view.entry(level + 1, parent, e)) };
                layer_extreme<Max>(c, sel, m);
                return;
            }
            layer_extreme<Max>(find(level, n), sel, m);
        });
    }

    /// A node's tile entries and what their in-node neighbours hold, so that
    /// the ring of a tile whose 26 neighbours are tiles of the same node (most
    /// of a sparse tree's entries) is a lookup, not 26 (the rebuild after an
    /// update, index_updates.h, runs this for every entry of every node).
    /// Exactly what ring() computes there: a tile's layer is its value, and
    /// NaN never counts.
    struct NodeTiles {
        uint32_t dim = 0;                ///< entries per axis (16, 32)
        std::vector<float> hi, lo;       ///< max / min of the 3^3 tile values around
        std::vector<uint8_t> slow;       ///< on the node's face, or beside a child
        std::vector<float> raw_hi, raw_lo, tmp;

        bool fast(uint32_t e) const { return !slow[e]; }

        template <bool Max> void filter(std::vector<float> &v) {
            // separable 3-wide max (min) per axis, clamped to the node
            const uint32_t d = dim, strides[3] = { d * d, d, 1 };
            for (uint32_t stride : strides) {
                tmp = v;
                for (uint32_t e = 0; e < d * d * d; ++e) {
                    const uint32_t c = (e / stride) % d;
                    if (c > 0)
                        extend<Max>(v[e], tmp[e - stride]);
                    if (c + 1 < d)
                        extend<Max>(v[e], tmp[e + stride]);
                }
            }
        }

        void build(const Builder &b, int level, uint64_t node) {
            dim = level == 1 ? 16u : 32u;
            const uint32_t count = dim * dim * dim;
            raw_hi.assign(count, kNone);
            raw_lo.assign(count, std::numeric_limits<float>::infinity());
            std::vector<float> child(count, 0.f);
            for (uint32_t e = 0; e < count; ++e) {
                if (b.m_view.child_bit(level, node, e)) {
                    child[e] = 1.f;
                    continue;
                }
                const float v = b.bound_at(b.m_view.entry(level, node, e));
                raise(raw_hi[e], v);
                lower_to(raw_lo[e], v);
            }
            hi = raw_hi;
            lo = raw_lo;
            filter<true>(hi);
            filter<false>(lo);
            filter<true>(child); // (dilated: beside a child)
            slow.assign(count, 0);
            for (uint32_t e = 0; e < count; ++e) {
                const uint32_t i = e / (dim * dim), j = (e / dim) % dim, k = e % dim;
                slow[e] = child[e] > 0.f || i == 0 || j == 0 || k == 0 || i + 1 == dim ||
                          j + 1 == dim || k + 1 == dim;
            }
        }
    };

    /// What lower() needs of its own: its entries' bounds and controls, and
    /// its node's tiles (one per thread)
    struct Scratch {
        std::vector<float> entry = std::vector<float>(nanovdb_drjit::LOWER_ENTRY_COUNT);
        std::vector<Control> entry_control = std::vector<Control>(nanovdb_drjit::LOWER_ENTRY_COUNT);
        NodeTiles tiles;
    };

    /// The mean of a leaf's 512 values (NaN as 0)
    double leaf_mean(uint64_t leaf) const {
        double sum = 0.0;
        for (uint32_t n = 0; n < 512; ++n) {
            const float v = m_codec.leaf_bound(m_buf + leaf, n);
            if (std::isfinite(v))
                sum += v;
        }
        return sum / 512.0;
    }

    // ---- Bottom-up: entries, then their node --------------------------------------

    /// An upper node at byte `node`, first voxel `o`: returns its M
    float upper(uint64_t node, const int32_t o[3]) {
        float M = kNone, R = kNone;
        Control control;
        NodeTiles &tiles = m_upper_tiles;
        tiles.build(*this, 2, node);
        for (uint32_t n = 0; n < layout::UPPER_TABLE_COUNT; ++n) {
            int32_t eo[3];
            m_view.entry_origin(2, o, n, eo);
            if (m_view.child_bit(2, node, n)) { // (lower_nodes() bounded it)
                const auto [M_child, child] = m_lower[index(1, m_view.child(2, node, n))];
                raise(M, M_child);
                add(control, child, layout::UPPER_TABLE_COUNT);
                continue;
            }
            const float v = start(bound_at(m_view.entry(2, node, n)));
            float r = v;
            if (tiles.fast(n))
                raise(r, tiles.hi[n]);
            else
                ring(1, eo, r, node);
            raise(M, r);
            // (an index grid's walk cannot read a tile's value, only R)
            if (r > v || m_codec.indexed())
                raise(R, r);
            add(control, tile_control(1, eo, v, node, n, tiles), layout::UPPER_TABLE_COUNT);
        }
        const size_t i = index(2, node);
        const uint32_t slot = m_out.layout.upper_slot + nanovdb_drjit::UPPER_SLOTS * uint32_t(i);
        store(slot, M, R, m_upper_min[i]);
        put_bits(slot + nanovdb_drjit::UPPER_CONTROL_SLOT,
                 nanovdb_drjit::control_bits<16>(m_out.values[slot], float(control.mean), control.lo));
        return M;
    }

    /// A tile of value v (start()ed) whose cell at `level` starts at o
    /// (entry e of node `parent`, whose NodeTiles are `tiles`): its control
    /// (the value; the smallest of it and its ring)
    Control tile_control(int level, const int32_t o[3], float v, uint64_t parent, uint32_t e,
                         const NodeTiles &tiles) const {
        Control c;
        c.mean = std::isfinite(v) ? v : 0.0;
        c.lo = std::isnan(v) || v == kNone ? std::numeric_limits<float>::infinity() : v;
        if (c.lo > 0.f) { // (a lower bound is >= 0: the ring cannot matter)
            if (tiles.fast(e))
                lower_to(c.lo, tiles.lo[e]);
            else
                ring<false>(level, o, c.lo, parent);
        }
        return c;
    }

    /// Adds a part (one of `parts` equal ones) to a region's control
    static void add(Control &region, const Control &part, uint32_t parts) {
        region.mean += part.mean / double(parts);
        lower_to(region.lo, part.lo);
    }

    /// Stores a control word in a slot of the float table
    void put_bits(uint32_t slot, uint32_t bits) { std::memcpy(&m_out.values[slot], &bits, 4); }

    /// A lower node at byte `node`, first voxel `o`: returns its M and control
    std::pair<float, Control> lower(uint64_t node, const int32_t o[3], Scratch &scratch) {
        std::vector<float> &m_entry = scratch.entry;
        std::vector<Control> &m_entry_control = scratch.entry_control;
        float M = kNone, R = kNone;
        Control control, bricks[nanovdb_drjit::LOWER_BRICK_COUNT];
        float brick[nanovdb_drjit::LOWER_BRICK_COUNT], brick_lo[nanovdb_drjit::LOWER_BRICK_COUNT];
        std::fill(std::begin(brick), std::end(brick), kNone);
        std::fill(std::begin(brick_lo), std::end(brick_lo), std::numeric_limits<float>::infinity());
        NodeTiles &tiles = scratch.tiles;
        tiles.build(*this, 1, node);
        for (uint32_t n = 0; n < layout::LOWER_TABLE_COUNT; ++n) {
            int32_t eo[3];
            m_view.entry_origin(1, o, n, eo);
            float r, lo;
            if (m_view.child_bit(1, node, n)) {
                const uint64_t leaf = m_view.child(1, node, n);
                const size_t i = index(0, leaf);
                r = m_grid.leaf_max()[i];
                lo = m_grid.leaf_min()[i];
                ring(0, eo, r, node);
                raise(m_out.values[m_out.layout.leaf_slot(uint32_t(leaf / 4))], r);
                m_entry_control[n] = { m_grid.leaf_max()[i] > 0.f ? leaf_mean(leaf) : 0.0, lo };
                if (lo > 0.f) // (a lower bound is >= 0: the ring cannot matter)
                    ring<false>(0, eo, m_entry_control[n].lo, node);
            } else {
                const float v = start(bound_at(m_view.entry(1, node, n)));
                r = lo = v;
                if (tiles.fast(n))
                    raise(r, tiles.hi[n]);
                else
                    ring(0, eo, r, node);
                if (r > v)
                    raise(R, r);
                m_entry_control[n] = tile_control(0, eo, v, node, n, tiles);
            }
            raise(M, r);
            const uint32_t b = nanovdb_drjit::brick_of(uint32_t(n >> 8) << 3,
                                                       uint32_t((n >> 4) & 15) << 3,
                                                       uint32_t(n & 15) << 3);
            raise(brick[b], r);
            lower_to(brick_lo[b], lo);
            m_entry[n] = r;
            add(bricks[b], m_entry_control[n],
                nanovdb_drjit::LOWER_ENTRY_COUNT / nanovdb_drjit::LOWER_BRICK_COUNT);
            add(control, m_entry_control[n], nanovdb_drjit::LOWER_ENTRY_COUNT);
        }
        const size_t i = index(1, node);
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
        // The entries' bounds, 8-bit fractions of their brick's (final) M,
        // raised: a fraction of a smaller M stays a bound under a larger one;
        // and their controls, fractions of the bound the walk computes from
        // that fraction (child_bound)
        auto brick_M = [&](uint32_t b) {
            return m_out.values[slot + nanovdb_drjit::LOWER_BRICK_M_SLOT + b];
        };
        for (uint32_t w = 0; w < nanovdb_drjit::LOWER_ENTRY_COUNT / 4; ++w) {
            float &word = m_out.values[slot + nanovdb_drjit::LOWER_ENTRY_FRACTION_SLOT + w];
            uint32_t bits, controls = 0;
            std::memcpy(&bits, &word, 4);
            for (uint32_t k = 0; k < 4; ++k) {
                const uint32_t n = 4 * w + k;
                const uint32_t b = nanovdb_drjit::brick_of(uint32_t(n >> 8) << 3,
                                                           uint32_t((n >> 4) & 15) << 3,
                                                           uint32_t(n & 15) << 3);
                const uint32_t q = std::max((bits >> (8 * k)) & 255u,
                                            nanovdb_drjit::child_fraction(brick_M(b), m_entry[n]));
                bits = (bits & ~(255u << (8 * k))) | (q << (8 * k));
                controls |= nanovdb_drjit::control_bits<4>(nanovdb_drjit::child_bound(brick_M(b), q),
                                                           float(m_entry_control[n].mean),
                                                           m_entry_control[n].lo)
                            << (8 * k);
            }
            std::memcpy(&word, &bits, 4);
            put_bits(slot + nanovdb_drjit::LOWER_ENTRY_CONTROL_SLOT + w, controls);
        }
        // The bricks' and the node's controls, fractions of their M
        for (uint32_t w = 0; w < nanovdb_drjit::LOWER_BRICK_COUNT / 4; ++w) {
            uint32_t bits = 0;
            for (uint32_t k = 0; k < 4; ++k) {
                const uint32_t b = 4 * w + k;
                bits |= nanovdb_drjit::control_bits<4>(brick_M(b), float(bricks[b].mean), bricks[b].lo)
                        << (8 * k);
            }
            put_bits(slot + nanovdb_drjit::LOWER_BRICK_CONTROL_SLOT + w, bits);
        }
        put_bits(slot + nanovdb_drjit::LOWER_CONTROL_SLOT,
                 nanovdb_drjit::control_bits<16>(m_out.values[slot], float(control.mean), control.lo));
        return { M, control };
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
        for (uint32_t t : m_view.tiles()) {
            int32_t o[3];
            m_view.tile_origin(t, o);
            const uint64_t child = m_view.tile_child(t);
            const Cover self = child != 0 ? Cover{ 2, child, 0.f }
                                          : Cover{ -1, 0, bound_at(m_view.tile_value(t)) };
            for_each_neighbour(o, layout::ROOT_TILE_LOG2, true,
                               [&](const int32_t n[3], const Layer sel[3]) {
                                   uint32_t covering;
                                   if (!m_view.tile_of(n, covering))
                                       layer_extreme(self, sel, m);
                               });
        }
        m_out.values[m_out.layout.background_slot] = m;
    }

    const unsigned m_threads; ///< lower_nodes()'s threads (0: one per core)
    const ValidatedGrid &m_grid;
    const TreeView m_view;
    const uint8_t *m_buf;
    const detail::ValueCodec m_codec;
    const uint32_t m_ring; ///< the ring's thickness in voxels (1-8)
    float m_background = 0.f;
    std::vector<float> m_lower_min, m_lower_max, m_upper_min, m_upper_max; ///< no ring
    std::vector<std::pair<float, Control>> m_lower; ///< lower nodes' M and control (lower_nodes())
    NodeTiles m_upper_tiles; ///< the upper node upper() is at
    NodeMajorants m_out;
};

} // namespace

NodeMajorants node_majorants(const ValidatedGrid &grid, int ring, unsigned threads) {
    return Builder(grid, ring, threads).run();
}

} // namespace nanovdb_loader
