/*
    nanovdb_drjit/majorant_rebuild.h -- an index grid's majorant table,
    rebuilt on the backend from its values (params.update() in an
    optimization), with no host round trip: LLVM and CUDA

    Beyond PNanoVDB. The same table, bit for bit, as the loader's
    node_majorants (src/loader/node_majorants.cpp) computes on the host from
    the same values, in the layout majorant_table.h describes, as
    MajorantGrid::make writes it (value slots times `factor`, bits as they
    are). The tree's part is read once at load (rebuild_plan.h); each pass
    here is a kernel or two over the cells of one level, bottom-up:

      1. each value index's bound (its largest channel) and smallest channel;
      2. the leaves, a plane of 8 x 8 voxels per lane, then a leaf: max and
         min over each of the 27 layers of a leaf (per axis: all of it, its
         `ring` lowest or highest voxels; a packet of 32 a leaf), the mean,
         the smallest channel: what a neighbour's ring reads of it;
      3. the lower nodes' entries: the ringed max and min of a leaf or a
         tile (rings(): a 3^3 filter of the node's tile values with the
         values beyond its faces, and the 26 neighbouring cells where a
         child or another node of the level is near), then,
         a lane each in brick order, the bricks and the node by block
         reductions; the 8-bit fractions and controls, four entries to a
         word;
      4. the lower nodes' layers (what an upper tile's ring reads of them);
      5. the upper nodes' entries, the same way, and their layers;
      6. the root tiles and the background; and, in a pass of its own
         when asked, the mean bound (local_majorant_ratio) of the table.

    The first call records its kernels, later ones replay them on the new
    values (kernel_replay.h): the host traces nothing. The mean bound is a
    pass of its own (mean()), run when asked. Measured (llvm_ad_rgb, 2
    cores): 3.2 ms for cloudfield_400's 1.8 M values (4.9 with the mean),
    against 36 ms for the host's passes (bench/PERF_LOG.md §46, §48).

    Sums of means (the controls' c) are added in another order than the
    host's: a control can differ where its c lies within rounding of a
    quantization step's middle (none on the test grids).
*/

#pragma once

#include "kernel_replay.h"
#include "layout.h"
#include "majorant_table.h"
#include "majorant_walk.h"
#include "rebuild_plan.h"

#include <drjit/jit.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

namespace nanovdb_drjit {

template <typename Float> class MajorantRebuild {
    static_assert(drjit::is_jit_v<Float>, "the rebuild runs on the LLVM or CUDA backend");
    using UInt32 = drjit::uint32_array_t<Float>;
    using Int32 = drjit::int32_array_t<Float>;
    using UInt64 = drjit::uint64_array_t<Float>;
    using Float64 = drjit::float64_array_t<Float>;
    using Mask = drjit::mask_t<Float>;
    static constexpr float Inf = std::numeric_limits<float>::infinity();

public:
    MajorantRebuild() = default;

    /// `leaf_chunk`, `lower_chunk`: leaves and lower nodes per pass (the
    /// defaults bound a pass's arrays to about 45 MB; the tests take small
    /// ones, to see the chunks join)
    explicit MajorantRebuild(const MajorantRebuildPlan &p, uint32_t leaf_chunk = 1u << 16,
                             uint32_t lower_chunk = 256)
        : m_leaf_chunk(std::max(leaf_chunk, 1u)), m_lower_chunk(std::max(lower_chunk, 1u)),
          m_layout(p.layout), m_ring(p.ring), m_leaves(p.leaf_count), m_lowers(p.lower_count),
          m_uppers(p.upper_count), m_tiles(uint32_t(p.tile_index.size())),
          m_background_index(p.background_index),
          m_background_pairs(uint32_t(p.background_codes.size())) {
        m_at.leaf_begin = drjit::opaque<UInt32>(p.layout.leaf_begin_word);
        m_at.leaf_words = drjit::opaque<UInt32>(p.leaf_words);
        m_at.lower_slot = drjit::opaque<UInt32>(p.layout.lower_slot);
        m_at.upper_slot = drjit::opaque<UInt32>(p.layout.upper_slot);
        m_at.tile_slot = drjit::opaque<UInt32>(p.layout.tile_slot);
        m_at.background_slot = drjit::opaque<UInt32>(p.layout.background_slot);
        m_lower_entries = load(p.lower_entries);
        m_upper_entries = load(p.upper_entries);
        m_lower_around = load(p.lower_around);
        m_upper_around = load(p.upper_around);
        m_tile_codes = load(p.tile_codes);
        m_tile_around = load(p.tile_around);
        m_tile_index = drjit::load<UInt32>(p.tile_index.data(), p.tile_index.size());
        m_background_codes = load(p.background_codes);
        m_background_layers =
            drjit::load<UInt32>(p.background_layers.data(), p.background_layers.size());
        m_lower_origins = load(p.lower_origins);
        m_upper_origins = load(p.upper_origins);
        m_tile_origins = load(p.tile_origins);
        m_lower_parent = drjit::load<UInt32>(p.lower_parent.data(), p.lower_parent.size());
        m_lower_slow = drjit::load<UInt32>(p.lower_slow.data(), p.lower_slow.size());
        for (uint32_t first = 0; first < m_lowers; first += m_lower_chunk)
            m_lower_slow_begin.push_back(uint32_t(
                std::lower_bound(p.lower_slow.begin(), p.lower_slow.end(), first * LOWER_ENTRY_COUNT) -
                p.lower_slow.begin()));
        m_lower_slow_begin.push_back(uint32_t(p.lower_slow.size()));
        m_upper_slow = drjit::load<UInt32>(p.upper_slow.data(), p.upper_slow.size());
    }

    /// The box of mean_bound() (voxels, inclusive) and the clamp of its bounds
    struct Box {
        int32_t lo[3], hi[3];
        float clamp;
    };

    bool valid() const { return m_layout.size != 0; }

    /// About the bytes of the arrays a rebuild allocates and frees (its
    /// largest passes' at once: a chunk of planes, the leaves' layers, a
    /// chunk of lower nodes' entries, the upper nodes' entries)
    size_t scratch_bytes() const {
        const size_t leaves = m_leaves, lowers = m_lowers, uppers = m_uppers;
        return std::min<size_t>(leaves, m_leaf_chunk) * 8 * 84 + leaves * (2 * LEAF_STRIDE + 3) * 4 +
               std::min<size_t>(lowers, m_lower_chunk) * LOWER_ENTRY_COUNT * 40 +
               lowers * NODE_STRIDE * LOWER_DIM * LOWER_DIM * 8 +
               uppers * UPPER_DIM * UPPER_DIM * UPPER_DIM * 40;
    }
    uint32_t background_slot() const { return m_layout.background_slot; }

    /// The table's words from the grid's words and its values (`channels`
    /// floats per value index 1, 2, ...; `background`: index 0's)
    UInt32 table(const UInt32 &grid, const Float &values, uint32_t channels,
                 const float background[3], float factor) const {
        namespace dr = drjit;
        // Replayed (kernel_replay.h): inputs the values, the tree and the
        // plan's arrays; constants the rest, the key
        std::vector<uint32_t> inputs = plan_inputs();
        inputs.insert(inputs.end(), { grid.index(), values.index() });
        const std::vector<uint32_t> out =
            m_replay.run(dr::backend_v<Float>, inputs, key(channels, background, factor, nullptr),
                         [&]() {
                             return std::vector<uint32_t>{
                                 traced_table(grid, values, channels, background, factor).release()
                             };
                         });
        return UInt32::steal(out[0]);
    }

    /// The loader's mean_bound() over `box` of a table() of these values (to
    /// rounding: from the value slots / factor, summed in another order), a
    /// JIT variable of one entry. A pass of its own, replayed on its own:
    /// only the walk's choice of majorants reads it (local_majorant_ratio)
    Float64 mean(const UInt32 &table, const Float &values, uint32_t channels,
                 const float background[3], float factor, const Box &box) const {
        namespace dr = drjit;
        // (inputs: the clamp too, max(), which updates change)
        const Float clamp = dr::opaque<Float>(box.clamp);
        std::vector<uint32_t> inputs = plan_inputs();
        inputs.insert(inputs.end(), { table.index(), values.index(), clamp.index() });
        const std::vector<uint32_t> out =
            m_mean_replay.run(dr::backend_v<Float>, inputs, key(channels, background, factor, &box),
                              [&]() {
                                  Bounds bound, low;
                                  value_bounds(values, channels, background, bound, low);
                                  Float64 m = mean_bound(table, bound, box, factor, clamp);
                                  dr::eval(m);
                                  return std::vector<uint32_t>{ m.release() };
                              });
        return Float64::steal(out[0]);
    }

    /// The replays (kernel_replay.h) of table() and of mean()
    const KernelReplay &replay() const { return m_replay; }
    const KernelReplay &mean_replay() const { return m_mean_replay; }

private:
    /// The plan's arrays, which every pass reads
    std::vector<uint32_t> plan_inputs() const {
        return { m_at.leaf_begin.index(), m_at.leaf_words.index(), m_at.lower_slot.index(),
                 m_at.upper_slot.index(), m_at.tile_slot.index(), m_at.background_slot.index(),
                 m_lower_entries.index(), m_upper_entries.index(), m_lower_around.index(),
                 m_upper_around.index(), m_tile_codes.index(), m_tile_around.index(),
                 m_tile_index.index(), m_background_codes.index(), m_background_layers.index(),
                 m_lower_origins.index(), m_upper_origins.index(), m_tile_origins.index(),
                 m_lower_parent.index(), m_lower_slow.index(), m_upper_slow.index() };
    }

    /// A pass's constants (a replay must see the same)
    static std::vector<uint64_t> key(uint32_t channels, const float background[3], float factor,
                                     const Box *box) {
        auto bits32 = [](float f) {
            uint32_t u;
            std::memcpy(&u, &f, 4);
            return uint64_t(u);
        };
        std::vector<uint64_t> k = { channels, bits32(background[0]), bits32(background[1]),
                                    bits32(background[2]), bits32(factor) };
        if (box)
            for (int a = 0; a < 3; ++a)
                k.insert(k.end(), { uint64_t(uint32_t(box->lo[a])), uint64_t(uint32_t(box->hi[a])) });
        return k;
    }

    /// table(), traced
    UInt32 traced_table(const UInt32 &grid, const Float &values, uint32_t channels,
                        const float background[3], float factor) const {
        namespace dr = drjit;
        Bounds bound, low;
        value_bounds(values, channels, background, bound, low);
        Leaves leaves = leaf_layers(grid, bound, low, channels);
        UInt32 out = dr::full<UInt32>(0xff800000u, m_layout.size); // (-Inf: a slot nobody writes)
        Lowers lowers = lower_nodes(leaves, bound, factor, out);
        Float lower_max, lower_min;
        node_layers(m_lower_entries, LOWER_DIM, m_lowers, leaves.max, leaves.min, bound, lower_max,
                    lower_min);
        Float upper_M = upper_nodes(lowers, lower_max, lower_min, bound, factor, out);
        Float upper_max, upper_min;
        node_layers(m_upper_entries, UPPER_DIM, m_uppers, lower_max, lower_min, bound, upper_max,
                    upper_min);
        tiles(upper_M, upper_max, bound, factor, out);
        dr::eval(out);
        return out;
    }

    static constexpr uint32_t LOWER_DIM = 16, UPPER_DIM = 32;
    /// A leaf's 27 layers in its arrays: leaf * LEAF_STRIDE + layer (a
    /// packet of a power of two, written at once); an internal node's, * 27
    static constexpr uint32_t LEAF_STRIDE = 32, NODE_STRIDE = 27;
    /// The stride of the layers of a node's children (entries per axis `dim`)
    static uint32_t child_stride(uint32_t dim) { return dim == LOWER_DIM ? LEAF_STRIDE : NODE_STRIDE; }

    static Int32 load(const std::vector<int32_t> &v) {
        return drjit::load<Int32>(v.data(), v.size());
    }
    static UInt32 bits(const Float &v) { return drjit::reinterpret_array<UInt32>(v); }
    static void schedule(Float *v, int n) {
        for (int k = 0; k < n; ++k)
            drjit::schedule(v[k]);
    }

    /// Per value index (0: the background), a bound: its largest channel,
    /// or its smallest. One channel: the values themselves, read in place
    struct Bounds {
        Float array;
        bool shifted = false; ///< array[i - 1] is index i's; `background` index 0's
        Float background;

        Float at(const UInt32 &index, const Mask &active = true) const {
            namespace dr = drjit;
            if (!shifted)
                return dr::gather<Float>(array, index, active);
            const Mask stored = index != 0u;
            return dr::select(stored, dr::gather<Float>(array, index - 1u, active && stored),
                              background);
        }
    };

    static void value_bounds(const Float &values, uint32_t channels, const float background[3],
                             Bounds &bound, Bounds &low) {
        namespace dr = drjit;
        if (channels != 3) {
            bound = low = Bounds{ values, true, dr::opaque<Float>(background[0]) };
            return;
        }
        const uint32_t count = uint32_t(dr::width(values) / channels);
        const UInt32 index = dr::arange<UInt32>(count + 1);
        const Mask stored = index > 0u;
        const UInt32 first = channels * (index - 1u);
        Float hi = dr::gather<Float>(values, first, stored), lo = hi;
        float bg_hi = background[0], bg_lo = background[0];
        for (uint32_t k = 1; k < 3; ++k) {
            const Float c = dr::gather<Float>(values, first + k, stored);
            hi = dr::maximum(hi, c);
            lo = dr::minimum(lo, c);
            bg_hi = std::max(bg_hi, background[k]);
            bg_lo = std::min(bg_lo, background[k]);
        }
        bound = Bounds{ dr::select(stored, hi, dr::opaque<Float>(bg_hi)), false, Float() };
        low = Bounds{ dr::select(stored, lo, dr::opaque<Float>(bg_lo)), false, Float() };
        dr::eval(bound.array, low.array);
    }

    // ---- 2. The leaves' layers ----------------------------------------------------

    /// Per leaf: max and min over each of its 27 layers (leaf * LEAF_STRIDE + layer),
    /// the mean of its voxels' bounds, its smallest channel
    struct Leaves {
        Float max, min, low;
        Float64 mean;
    };

    /// max / min of `v` into the three parts of an axis that coordinate c (of
    /// 8) is in: all, its first `ring`, its last `ring`
    void add_to_parts(uint32_t c, const Float &hi, const Float &lo, Float mx[3], Float mn[3]) const {
        namespace dr = drjit;
        mx[0] = dr::maximum(mx[0], hi);
        mn[0] = dr::minimum(mn[0], lo);
        if (c < m_ring) {
            mx[1] = dr::maximum(mx[1], hi);
            mn[1] = dr::minimum(mn[1], lo);
        }
        if (c + m_ring >= 8) {
            mx[2] = dr::maximum(mx[2], hi);
            mn[2] = dr::minimum(mn[2], lo);
        }
    }

    /// Leaves [first, first + count) into `out` (allocated for all)
    void leaf_layers(const UInt32 &grid, const Bounds &bound, const Bounds &low, uint32_t channels,
                     uint32_t first_leaf, uint32_t count, Leaves &out) const {
        namespace dr = drjit;
        const UInt32 leaf0 = dr::opaque<UInt32>(first_leaf); // (one kernel for every chunk)
        const GridTypeConstants &c = GRID_TYPE_CONSTANTS_ONINDEX;
        // Planes (leaf, x): 3 x 3 parts in (y, z), a row of 8 voxels along z
        // at a time, their value indices from the leaf's mask (its word x
        // holds the plane), first index and prefix sums (PNanoVDB's
        // pnanovdb_leaf_onindex_get_value_index)
        Float plane_max[9], plane_min[9], plane_low;
        Float64 plane_sum;
        {
            const UInt32 lane = dr::arange<UInt32>(count * 8u);
            const UInt32 x = lane & 7u;
            const UInt32 leaf = m_at.leaf_begin + (leaf0 + (lane >> 3)) * m_at.leaf_words;
            const UInt32 table = leaf + c.leaf_off_table / 4;
            auto u64 = [&](const UInt32 &at) {
                return UInt64(dr::gather<UInt32>(grid, at)) |
                       (UInt64(dr::gather<UInt32>(grid, at + 1u)) << 32);
            };
            const UInt64 mask = u64(leaf + LEAF_OFF_VALUE_MASK / 4 + 2u * x),
                         prefix = u64(table + ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM / 4);
            const UInt32 first = dr::gather<UInt32>(grid, table) + // (< 2^31: the plan)
                dr::select(x > 0u, UInt32((prefix >> UInt64(9u * dr::select(x > 0u, x - 1u, 0u))) & 511u), 0u);
            for (int k = 0; k < 9; ++k) {
                plane_max[k] = dr::full<Float>(-Inf, count * 8u);
                plane_min[k] = dr::full<Float>(Inf, count * 8u);
            }
            plane_low = dr::full<Float>(Inf, count * 8u);
            plane_sum = dr::zeros<Float64>(count * 8u);
            // A row's parts along z, its voxels' indices counted from `next`
            auto row = [&](uint32_t y, UInt32 &next, Float row_max[3], Float row_min[3],
                           Float64 *sum, Float *lowest) {
                const UInt32 byte = UInt32(mask >> (8 * y)) & 255u;
                for (int k = 0; k < 3; ++k) {
                    row_max[k] = -Inf;
                    row_min[k] = Inf;
                }
                for (uint32_t z = 0; z < 8; ++z) {
                    const Mask on = ((byte >> z) & 1u) != 0u;
                    const UInt32 index = dr::select(on, next, 0u);
                    next += dr::select(on, 1u, 0u);
                    const Float b = bound.at(index);
                    add_to_parts(z, b, b, row_max, row_min);
                    if (lowest)
                        *lowest = dr::minimum(*lowest, low.at(index));
                    if (sum)
                        *sum += Float64(dr::select(dr::isfinite(b), b, 0.f));
                }
            };
            // The parts of all y (0, 1, 2), the sum, the smallest channel
            // from every row; the first and last `ring` rows' parts (3 to 8)
            // from those rows, read last: their 12 accumulators, held through
            // the loop, did not fit the registers (the kernel took 1.6x as long)
            auto row_first = [&](uint32_t y) {
                return y == 0 ? first
                              : first + UInt32(dr::popcnt(mask & ((uint64_t(1) << (8 * y)) - 1u)));
            };
            auto all_y = [&](const Float row_max[3], const Float row_min[3]) {
                for (uint32_t kz = 0; kz < 3; ++kz) {
                    plane_max[kz] = dr::maximum(plane_max[kz], row_max[kz]);
                    plane_min[kz] = dr::minimum(plane_min[kz], row_min[kz]);
                }
            };
            auto edge = [&](uint32_t y) { return y < m_ring || y + m_ring >= 8; };
            // (the middle rows, y in [ring, 8 - ring), one after the other)
            UInt32 next = 2 * m_ring < 8 ? row_first(m_ring) : UInt32();
            for (uint32_t y = 0; y < 8; ++y) {
                if (edge(y))
                    continue;
                Float row_max[3], row_min[3];
                row(y, next, row_max, row_min, &plane_sum, channels == 3 ? &plane_low : nullptr);
                all_y(row_max, row_min);
            }
            for (uint32_t y = 0; y < 8; ++y) {
                if (!edge(y))
                    continue;
                UInt32 at = row_first(y);
                Float row_max[3], row_min[3];
                row(y, at, row_max, row_min, &plane_sum, channels == 3 ? &plane_low : nullptr);
                all_y(row_max, row_min);
                for (uint32_t kz = 0; kz < 3; ++kz) {
                    Float mx[3] = { Float(-Inf), plane_max[3 + kz], plane_max[6 + kz] },
                          mn[3] = { Float(Inf), plane_min[3 + kz], plane_min[6 + kz] };
                    add_to_parts(y, row_max[kz], row_min[kz], mx, mn);
                    for (uint32_t ky = 1; ky < 3; ++ky) {
                        plane_max[3 * ky + kz] = mx[ky];
                        plane_min[3 * ky + kz] = mn[ky];
                    }
                }
            }
            if (channels != 3) // (one channel: the smallest is the bound)
                plane_low = plane_min[0];
            schedule(plane_max, 9);
            schedule(plane_min, 9);
            dr::eval(plane_low, plane_sum);
        }
        // Leaves: 27 layers
        const UInt32 leaf = dr::arange<UInt32>(count);
        Float mx[27], mn[27], low_out = Inf;
        for (int k = 0; k < 27; ++k) {
            mx[k] = -Inf;
            mn[k] = Inf;
        }
        Float64 sum = 0.0;
        // (a leaf's 8 planes are adjacent: one packet each, read at once)
        using Planes = dr::Array<Float, 8>;
        for (uint32_t kyz = 0; kyz < 9; ++kyz) {
            const Planes hi = dr::gather<Planes>(plane_max[kyz], leaf),
                         lo = dr::gather<Planes>(plane_min[kyz], leaf);
            for (uint32_t x = 0; x < 8; ++x) {
                Float a[3] = { mx[kyz], mx[9 + kyz], mx[18 + kyz] },
                      b[3] = { mn[kyz], mn[9 + kyz], mn[18 + kyz] };
                add_to_parts(x, hi[x], lo[x], a, b);
                for (uint32_t kx = 0; kx < 3; ++kx) {
                    mx[9 * kx + kyz] = a[kx];
                    mn[9 * kx + kyz] = b[kx];
                }
            }
        }
        {
            const Planes low_planes = dr::gather<Planes>(plane_low, leaf);
            const dr::Array<Float64, 8> sums = dr::gather<dr::Array<Float64, 8>>(plane_sum, leaf);
            for (uint32_t x = 0; x < 8; ++x) {
                low_out = dr::minimum(low_out, low_planes[x]);
                sum += sums[x];
            }
        }
        // One packet of LEAF_STRIDE a leaf (27 scatters into one array were
        // 27 kernels: a scatter into an array with one pending evaluates it)
        const UInt32 at = leaf0 + leaf;
        dr::Array<Float, LEAF_STRIDE> pmx, pmn;
        for (uint32_t k = 0; k < LEAF_STRIDE; ++k) {
            pmx[k] = k < 27 ? mx[k] : Float(-Inf);
            pmn[k] = k < 27 ? mn[k] : Float(Inf);
        }
        dr::scatter(out.max, pmx, at);
        dr::scatter(out.min, pmn, at);
        dr::scatter(out.low, low_out, at);
        dr::scatter(out.mean, sum * (1.0 / 512.0), at);
        dr::eval(out.max, out.min, out.low, out.mean);
    }

    /// The leaves' layers, in chunks of m_leaf_chunk leaves (the planes'
    /// arrays: 84 bytes a plane)
    Leaves leaf_layers(const UInt32 &grid, const Bounds &bound, const Bounds &low,
                       uint32_t channels) const {
        namespace dr = drjit;
        Leaves out;
        out.max = dr::zeros<Float>(m_leaves * LEAF_STRIDE);
        out.min = dr::zeros<Float>(m_leaves * LEAF_STRIDE);
        out.low = dr::zeros<Float>(m_leaves);
        out.mean = dr::zeros<Float64>(m_leaves);
        for (uint32_t first = 0; first < m_leaves; first += m_leaf_chunk)
            leaf_layers(grid, bound, low, channels, first, std::min(m_leaf_chunk, m_leaves - first),
                        out);
        return out;
    }

    // ---- 3.-5. Internal nodes ------------------------------------------------------

    /// The ringed max and min of the cell of entry (x, y, z) of node `node`
    /// (entries per axis `dim`): the layers of its 26 neighbouring cells that
    /// touch it (a child's from `child_max`/`child_min`, child * child_stride() +
    /// layer; a value's bound)
    void ring(const Int32 &entries, const Int32 &around, uint32_t dim, const UInt32 &node,
              const UInt32 xyz[3], const Float &child_max, const Float &child_min,
              const Bounds &bound, Float &mx, Float &mn) const {
        namespace dr = drjit;
        const uint32_t log2 = dim == LOWER_DIM ? 4 : 5, count = dim * dim * dim;
        for_each_direction([&](int dx, int dy, int dz) {
            const int d[3] = { dx, dy, dz };
            UInt32 side = dr::zeros<UInt32>(), at = dr::zeros<UInt32>();
            for (int a = 0; a < 3; ++a) {
                const UInt32 c = xyz[a] + uint32_t(d[a]); // (wraps below 0)
                // 0: the node below, 1: this one, 2: the one above
                const UInt32 s = dr::select(c == uint32_t(-1), 0u, dr::select(c == dim, 2u, 1u));
                side = side * 3u + s;
                at = (at << log2) | (c & (dim - 1u));
            }
            const Int32 node_code = dr::gather<Int32>(around, node * 27u + side);
            const Mask in_node = node_code >= 0;
            const Int32 code = dr::select(
                in_node, dr::gather<Int32>(entries, UInt32(node_code) * count + at, in_node),
                node_code);
            const Mask child = code >= 0;
            const uint32_t layer = layer_of_direction(dx, dy, dz, false);
            const Float v = bound.at(UInt32(-1 - code), !child);
            const UInt32 ci = UInt32(code) * child_stride(dim) + layer;
            mx = dr::maximum(mx, dr::select(child, dr::gather<Float>(child_max, ci, child), v));
            mn = dr::minimum(mn, dr::select(child, dr::gather<Float>(child_min, ci, child), v));
        });
    }

    /// Per node [first_node, first_node + nodes) and class of entry (9 x +
    /// 3 y + z; per axis 0: the low face, 1: inside, 2: the high face): the
    /// max and min of the values of the node-sized cells beyond the node that
    /// such an entry touches (-Inf and Inf: none, or a node)
    void beyond(const Int32 &around, uint32_t first_node, uint32_t nodes, const Bounds &bound,
                Float &out_max, Float &out_min) const {
        namespace dr = drjit;
        const UInt32 lane = dr::arange<UInt32>(nodes * 27u);
        const UInt32 node = dr::opaque<UInt32>(first_node) + lane / 27u, cls = lane % 27u;
        const UInt32 k[3] = { cls / 9u, (cls / 3u) % 3u, cls % 3u };
        out_max = dr::full<Float>(-Inf, nodes * 27u);
        out_min = dr::full<Float>(Inf, nodes * 27u);
        for_each_direction([&](int dx, int dy, int dz) {
            const int d[3] = { dx, dy, dz };
            Mask touched = true;
            for (int a = 0; a < 3; ++a)
                if (d[a] != 0)
                    touched &= k[a] == (d[a] < 0 ? 0u : 2u);
            const Int32 code =
                dr::gather<Int32>(around, node * 27u + direction_index(dx, dy, dz), touched);
            const Mask value = touched && code < 0;
            const Float v = bound.at(UInt32(-1 - code), value);
            out_max = dr::maximum(out_max, dr::select(value, v, -Inf));
            out_min = dr::minimum(out_min, dr::select(value, v, Inf));
        });
        dr::eval(out_max, out_min);
    }

    /// The ringed max and min (ring()) of every entry of every node of a
    /// level, in entry order (node * dim^3 + entry). Most entries of a
    /// sparse tree are tiles whose 26 neighbours are tiles of their own node:
    /// theirs is the max and min of the 3^3 tile values around, a separable
    /// filter (three passes of three); ring() itself runs only on the others
    /// (`slow`: children, tiles beside a child, entries beside a node of this
    /// level beyond the node; the plan's); the values beyond the node come
    /// from beyond()
    void rings(const Int32 &entries, const Int32 &around, const UInt32 &slow, uint32_t dim,
               uint32_t first_node, uint32_t nodes, const Float &child_max,
               const Float &child_min, const Bounds &bound, Float &mx, Float &mn) const {
        namespace dr = drjit;
        const uint32_t log2 = dim == LOWER_DIM ? 4 : 5, count = dim * dim * dim;
        const UInt32 lane = dr::arange<UInt32>(nodes * count);
        // (opaque: one kernel for every chunk of nodes)
        const UInt32 offset = dr::opaque<UInt32>(first_node * count);
        {
            const Int32 code = dr::gather<Int32>(entries, offset + lane);
            const Float v = bound.at(UInt32(-1 - code), code < 0);
            mx = dr::select(code < 0, v, -Inf);
            mn = dr::select(code < 0, v, Inf);
        }
        for (uint32_t a = 0; a < 3; ++a) {
            const uint32_t stride = 1u << (log2 * (2 - a));
            const UInt32 c = (lane >> (log2 * (2 - a))) & (dim - 1u);
            dr::eval(mx, mn);
            const Mask below = c > 0u, above = c + 1u < dim;
            auto side = [&](const Float &v, const UInt32 &at, const Mask &inside, float none) {
                return dr::select(inside, dr::gather<Float>(v, at, inside), none);
            };
            const Float hi = dr::maximum(side(mx, lane - stride, below, -Inf),
                                         side(mx, lane + stride, above, -Inf)),
                        lo = dr::minimum(side(mn, lane - stride, below, Inf),
                                         side(mn, lane + stride, above, Inf));
            mx = dr::maximum(mx, hi);
            mn = dr::minimum(mn, lo);
        }
        {
            // Entries on the node's faces, edges and corners: the values of
            // the node-sized cells beyond that they touch (27 classes of
            // entry per node: per axis the low face, inside, the high face;
            // a cell beyond that is a node of this level makes them slow)
            Float beyond_max, beyond_min;
            beyond(around, first_node, nodes, bound, beyond_max, beyond_min);
            UInt32 cls = dr::zeros<UInt32>();
            for (uint32_t a = 0; a < 3; ++a) {
                const UInt32 c = (lane >> (log2 * (2 - a))) & (dim - 1u);
                cls = cls * 3u + dr::select(c == 0u, 0u, dr::select(c == dim - 1u, 2u, 1u));
            }
            const UInt32 at = (lane >> (3 * log2)) * 27u + cls;
            mx = dr::maximum(mx, dr::gather<Float>(beyond_max, at));
            mn = dr::minimum(mn, dr::gather<Float>(beyond_min, at));
        }
        const uint32_t n = uint32_t(dr::width(slow));
        if (n > 0) {
            const UInt32 node = slow >> (3 * log2), e = slow & (count - 1u);
            const UInt32 xyz[3] = { e >> (2 * log2), (e >> log2) & (dim - 1u), e & (dim - 1u) };
            Float smx = dr::full<Float>(-Inf, n), smn = dr::full<Float>(Inf, n);
            ring(entries, around, dim, node, xyz, child_max, child_min, bound, smx, smn);
            dr::eval(mx, mn);
            dr::scatter(mx, smx, slow - offset);
            dr::scatter(mn, smn, slow - offset);
        }
        dr::eval(mx, mn);
    }

    /// Per node of `dim`^3 entries: the max and min over each of its 26
    /// layers of one entry's thickness (node * 27 + layer; layer 0, the
    /// whole node, is not computed: no ring reads it), from its children's
    /// same layers and its tiles' values
    void node_layers(const Int32 &entries, uint32_t dim, uint32_t nodes, const Float &child_max,
                     const Float &child_min, const Bounds &bound, Float &out_max,
                     Float &out_min) const {
        namespace dr = drjit;
        const uint32_t face = dim * dim, log2 = dim == LOWER_DIM ? 4 : 5;
        const UInt32 lane = dr::arange<UInt32>(nodes * 27u * face);
        const UInt32 t = lane % face, layer = (lane / face) % 27u, node = lane / (face * 27u);
        const UInt32 u = t >> log2, w = t & (dim - 1u);
        const UInt32 part[3] = { layer / 9u, (layer / 3u) % 3u, layer % 3u };
        const UInt32 alls = dr::select(part[0] == 0u, 1u, 0u) + dr::select(part[1] == 0u, 1u, 0u) +
                            dr::select(part[2] == 0u, 1u, 0u);
        // The axes that run along the layer take u and w (the first of two
        // takes u; the others w: an edge's entries repeat, which max and
        // min do not mind)
        const UInt32 free_coord[3] = { dr::select(alls == 2u, u, w),
                                       dr::select(alls == 2u && part[0] != 0u, u, w), w };
        UInt32 e = dr::zeros<UInt32>();
        for (int a = 0; a < 3; ++a)
            e = (e << log2) | dr::select(part[a] == 0u, free_coord[a],
                                         dr::select(part[a] == 1u, 0u, dim - 1u));
        const Int32 code = dr::gather<Int32>(entries, node * (face * dim) + e);
        const Mask child = code >= 0;
        const Float v = bound.at(UInt32(-1 - code), !child);
        const UInt32 ci = UInt32(code) * child_stride(dim) + layer;
        const Float hi = dr::select(child, dr::gather<Float>(child_max, ci, child), v),
                    lo = dr::select(child, dr::gather<Float>(child_min, ci, child), v);
        dr::eval(hi, lo); // (one kernel for both, then the reductions)
        out_max = dr::block_reduce(ReduceOp::Max, hi, face);
        out_min = dr::block_reduce(ReduceOp::Min, lo, face);
    }

    /// Per lower node: its M, its smallest value m, its control's c (a sum,
    /// / 4096) and L
    struct Lowers {
        Float M, m, low;
        Float64 sum;
    };

    static UInt32 brick_bits(const Float &M, const Float &m) {
        namespace dr = drjit;
        const Float q = 255.f * (m / M);
        UInt32 r = dr::select(q >= 255.f, 254u, UInt32(dr::select(q >= 0.f, q, 0.f)));
        r = dr::select(m >= M, 255u, r);
        return dr::select(!(M > 0.f) || !(m > 0.f), 0u, r);
    }

    /// child_fraction of majorant_table.h: its search starts one step below
    /// the answer, which is at most two steps further
    static UInt32 entry_fraction(const Float &M, const Float &r) {
        namespace dr = drjit;
        const Float64 want = Float64(r) * (1.0 + 1.0 / 4096.0);
        const Float64 start = dr::maximum(0.0, dr::floor(255.0 * want / Float64(M)));
        UInt32 q = UInt32(dr::minimum(start, 255.0));
        Mask found = q >= 255u;
        UInt32 out = dr::full<UInt32>(255u, dr::width(q));
        for (int step = 0; step < 4; ++step) {
            const Mask ok = !found && q < 255u && Float64(child_bound_of(M, q)) >= want;
            out = dr::select(ok, q, out);
            found |= ok;
            q += 1u;
        }
        return dr::select(!(r > 0.f) || !(M > 0.f), 0u, out);
    }

    /// control_bits of majorant_table.h, on the backend
    template <uint32_t Bits>
    static UInt32 control(const Float &M, const Float &c, const Float &L) {
        namespace dr = drjit;
        constexpr uint32_t top = (1u << Bits) - 1u;
        const Float64 M64(M);
        auto frac = [&](const Float &v) {
            return dr::clip(Float64(v) / M64, 0.0, 1.0) * double(top);
        };
        const Float64 fc = frac(c), fl = frac(L);
        const Float64 tc = dr::floor(fc); // (lround: halves away from 0)
        const UInt32 qc = UInt32(tc) + dr::select(fc - tc >= 0.5, 1u, 0u);
        UInt32 ql = UInt32(dr::floor(fl));
        ql = dr::select(ql == top && !(L >= M), top - 1u, ql);
        const UInt32 out = (qc << Bits) | dr::minimum(ql, qc);
        return dr::select(!(M > 0.f) || dr::isinf(M), 0u, out);
    }

    /// Lower nodes [first, first + nodes): their slots in `out`, their M, m,
    /// control L and sum of c into `lw` (allocated for all)
    void lower_nodes(const Leaves &leaves, const Bounds &bound, float factor, uint32_t first,
                     uint32_t nodes, uint32_t chunk, Lowers &lw, UInt32 &out) const {
        namespace dr = drjit;
        const uint32_t n = nodes * LOWER_ENTRY_COUNT;
        const UInt32 base = dr::opaque<UInt32>(first); // (one kernel for every chunk)
        Float ring_max, ring_min;
        {
            const uint32_t s0 = m_lower_slow_begin[chunk], s1 = m_lower_slow_begin[chunk + 1];
            const UInt32 slow =
                s1 > s0 ? dr::gather<UInt32>(m_lower_slow, dr::arange<UInt32>(s1 - s0) + dr::opaque<UInt32>(s0))
                        : UInt32();
            rings(m_lower_entries, m_lower_around, slow, LOWER_DIM, first, nodes, leaves.max,
                  leaves.min, bound, ring_max, ring_min);
        }
        // Entries, a lane each, brick by brick (64 lanes a brick)
        Float r, low, control_low, Rc;
        Float64 mean;
        {
            const UInt32 lane = dr::arange<UInt32>(n);
            const UInt32 local = lane >> 12, node = base + local, b = (lane >> 6) & 63u,
                         l = lane & 63u;
            const UInt32 xyz[3] = { ((b >> 4) << 2) | (l >> 4), (((b >> 2) & 3u) << 2) | ((l >> 2) & 3u),
                                    ((b & 3u) << 2) | (l & 3u) };
            const UInt32 e = (xyz[0] << 8) | (xyz[1] << 4) | xyz[2];
            const Int32 code = dr::gather<Int32>(m_lower_entries, (node << 12) + e);
            const Mask leaf = code >= 0;
            const UInt32 li = UInt32(code);
            const Float leaf_max = dr::gather<Float>(leaves.max, li * LEAF_STRIDE, leaf);
            const Float v = bound.at(UInt32(-1 - code), !leaf);
            const Float mx = dr::gather<Float>(ring_max, (local << 12) + e),
                        mn = dr::gather<Float>(ring_min, (local << 12) + e);
            r = dr::maximum(dr::select(leaf, leaf_max, v), mx);
            low = dr::select(leaf, dr::gather<Float>(leaves.low, li, leaf), v);
            control_low = dr::select(low > 0.f, dr::minimum(low, mn), low);
            mean = dr::select(leaf,
                              dr::select(leaf_max > 0.f, dr::gather<Float64>(leaves.mean, li, leaf), 0.0),
                              Float64(v));
            Rc = dr::select(!leaf && r > v, r, -Inf);
            dr::scatter(out, bits(r * factor), li, leaf);
            dr::eval(r, low, control_low, mean, Rc, out);
        }
        // Bricks and nodes
        const Float brick_M = dr::block_reduce(ReduceOp::Max, r, 64),
                    brick_low = dr::block_reduce(ReduceOp::Min, low, 64),
                    brick_control = dr::block_reduce(ReduceOp::Min, control_low, 64);
        const Float64 brick_sum = dr::block_reduce(ReduceOp::Add, mean, 64);
        {
            const Float M = dr::block_reduce(ReduceOp::Max, brick_M, 64),
                        R = dr::block_reduce(ReduceOp::Max, Rc, LOWER_ENTRY_COUNT),
                        m = dr::block_reduce(ReduceOp::Min, brick_low, 64),
                        low_node = dr::block_reduce(ReduceOp::Min, brick_control, 64);
            const Float64 sum = dr::block_reduce(ReduceOp::Add, brick_sum, 64);
            const UInt32 node = base + dr::arange<UInt32>(nodes);
            const UInt32 slot = m_at.lower_slot + LOWER_SLOTS * node;
            dr::scatter(out, bits(M * factor), slot);
            dr::scatter(out, bits(R * factor), slot + 1u);
            dr::scatter(out, bits(m * factor), slot + 2u);
            dr::scatter(out, control<16>(M, Float(sum * (1.0 / 4096.0)), low_node),
                        slot + LOWER_CONTROL_SLOT);
            dr::scatter(lw.M, M, node);
            dr::scatter(lw.m, m, node);
            dr::scatter(lw.low, low_node, node);
            dr::scatter(lw.sum, sum, node);
        }
        {
            const UInt32 brick = dr::arange<UInt32>(nodes * 64u);
            dr::scatter(out, bits(brick_M * factor),
                        m_at.lower_slot + LOWER_SLOTS * (base + (brick >> 6)) +
                            LOWER_BRICK_M_SLOT + (brick & 63u));
        }
        // Four bricks a word: their m as fractions, their controls
        {
            const UInt32 word = dr::arange<UInt32>(nodes * 16u);
            UInt32 fractions = dr::zeros<UInt32>(nodes * 16u), controls = fractions;
            for (uint32_t k = 0; k < 4; ++k) {
                const UInt32 brick = word * 4u + k;
                const Float M = dr::gather<Float>(brick_M, brick);
                fractions |= brick_bits(M, dr::gather<Float>(brick_low, brick)) << (8 * k);
                controls |= control<4>(M, Float(dr::gather<Float64>(brick_sum, brick) * (1.0 / 64.0)),
                                       dr::gather<Float>(brick_control, brick))
                            << (8 * k);
            }
            const UInt32 slot = m_at.lower_slot + LOWER_SLOTS * (base + (word >> 4)) + (word & 15u);
            dr::scatter(out, fractions, slot + LOWER_BRICK_FRACTION_SLOT);
            dr::scatter(out, controls, slot + LOWER_BRICK_CONTROL_SLOT);
        }
        // Four entries a word: their bounds as fractions of their brick's
        // M, their controls as fractions of those bounds
        {
            const UInt32 word = dr::arange<UInt32>(nodes * 1024u);
            const UInt32 node = word >> 10; // (in the chunk)
            UInt32 fractions = dr::zeros<UInt32>(nodes * 1024u), controls = fractions;
            for (uint32_t k = 0; k < 4; ++k) {
                const UInt32 e = ((word & 1023u) << 2) | k;
                const UInt32 x = e >> 8, y = (e >> 4) & 15u, z = e & 15u;
                const UInt32 b = ((x >> 2) << 4) | ((y >> 2) << 2) | (z >> 2);
                const UInt32 at = (node << 12) | (b << 6) | ((x & 3u) << 4) | ((y & 3u) << 2) | (z & 3u);
                const Float M = dr::gather<Float>(brick_M, (node << 6) | b);
                const UInt32 q = entry_fraction(M, dr::gather<Float>(r, at));
                fractions |= q << (8 * k);
                controls |= control<4>(child_bound_of(M, q), Float(dr::gather<Float64>(mean, at)),
                                       dr::gather<Float>(control_low, at))
                            << (8 * k);
            }
            const UInt32 slot = m_at.lower_slot + LOWER_SLOTS * (base + node) + (word & 1023u);
            dr::scatter(out, fractions, slot + LOWER_ENTRY_FRACTION_SLOT);
            dr::scatter(out, controls, slot + LOWER_ENTRY_CONTROL_SLOT);
        }
        dr::eval(out, lw.M, lw.m, lw.low, lw.sum);
    }

    /// The lower nodes in chunks of m_lower_chunk (their entries' arrays: 40
    /// bytes an entry)
    Lowers lower_nodes(const Leaves &leaves, const Bounds &bound, float factor, UInt32 &out) const {
        namespace dr = drjit;
        Lowers lw{ dr::zeros<Float>(m_lowers), dr::zeros<Float>(m_lowers), dr::zeros<Float>(m_lowers),
                   dr::zeros<Float64>(m_lowers) };
        for (uint32_t first = 0, chunk = 0; first < m_lowers; first += m_lower_chunk, ++chunk)
            lower_nodes(leaves, bound, factor, first, std::min(m_lower_chunk, m_lowers - first), chunk,
                        lw, out);
        return lw;
    }

    /// The upper nodes' slots; returns their M
    Float upper_nodes(const Lowers &lw, const Float &lower_max, const Float &lower_min,
                      const Bounds &bound, float factor, UInt32 &out) const {
        namespace dr = drjit;
        const uint32_t count = UPPER_DIM * UPPER_DIM * UPPER_DIM, n = m_uppers * count;
        const UInt32 lane = dr::arange<UInt32>(n);
        const Int32 code = dr::gather<Int32>(m_upper_entries, lane);
        const Mask child = code >= 0;
        const UInt32 ci = UInt32(code);
        const Float v = bound.at(UInt32(-1 - code), !child);
        Float mx, mn;
        rings(m_upper_entries, m_upper_around, m_upper_slow, UPPER_DIM, 0, m_uppers, lower_max,
              lower_min, bound, mx, mn);
        const Float r = dr::maximum(v, mx);
        // Per entry: what it adds to the node's M, R (an index grid's walk
        // reads no tile's value, only R: every tile's ringed bound raises
        // it), m, and control (L, c); evaluated once, for five reductions
        const Float e_M = dr::select(child, dr::gather<Float>(lw.M, ci, child), r),
                    e_R = dr::select(child, -Inf, r),
                    e_m = dr::select(child, dr::gather<Float>(lw.m, ci, child), v),
                    e_low = dr::select(child, dr::gather<Float>(lw.low, ci, child),
                                       dr::select(v > 0.f, dr::minimum(v, mn), v));
        const Float64 e_c =
            dr::select(child, dr::gather<Float64>(lw.sum, ci, child) * (1.0 / 4096.0), Float64(v));
        dr::eval(e_M, e_R, e_m, e_low, e_c);
        const Float M = dr::block_reduce(ReduceOp::Max, e_M, count),
                    R = dr::block_reduce(ReduceOp::Max, e_R, count),
                    m = dr::block_reduce(ReduceOp::Min, e_m, count),
                    low = dr::block_reduce(ReduceOp::Min, e_low, count);
        const Float64 sum = dr::block_reduce(ReduceOp::Add, e_c, count);
        const UInt32 slot = m_at.upper_slot + UPPER_SLOTS * dr::arange<UInt32>(m_uppers);
        dr::scatter(out, bits(M * factor), slot);
        dr::scatter(out, bits(R * factor), slot + 1u);
        dr::scatter(out, bits(m * factor), slot + 2u);
        dr::scatter(out, control<16>(M, Float(sum * (1.0 / double(count))), low),
                    slot + UPPER_CONTROL_SLOT);
        return M;
    }

    // ---- 6. Root tiles and the background -----------------------------------------

    void tiles(const Float &upper_M, const Float &upper_max, const Bounds &bound, float factor,
               UInt32 &out) const {
        namespace dr = drjit;
        if (m_tiles > 0) {
            const UInt32 tile = dr::arange<UInt32>(m_tiles);
            const Int32 code = dr::gather<Int32>(m_tile_codes, tile);
            const Mask child = code >= 0;
            Float e = bound.at(UInt32(-1 - code), !child);
            for_each_direction([&](int dx, int dy, int dz) {
                const Int32 c =
                    dr::gather<Int32>(m_tile_around, tile * 27u + direction_index(dx, dy, dz), !child);
                const Mask upper = c >= 0 && !child;
                const Float layer = dr::gather<Float>(
                    upper_max, UInt32(c) * NODE_STRIDE + layer_of_direction(dx, dy, dz, false), upper);
                e = dr::maximum(e, dr::select(upper, layer, bound.at(UInt32(-1 - c), !child && !upper)));
            });
            e = dr::select(child, dr::gather<Float>(upper_M, UInt32(code), child), e);
            dr::scatter(out, bits(e * factor),
                        m_at.tile_slot + dr::gather<UInt32>(m_tile_index, tile));
        }
        Float bg = bound.at(dr::opaque<UInt32>(m_background_index));
        if (m_background_pairs > 0) {
            const UInt32 pair = dr::arange<UInt32>(m_background_pairs);
            const Int32 code = dr::gather<Int32>(m_background_codes, pair);
            const Mask upper = code >= 0;
            const Float layer = dr::select(
                upper,
                dr::gather<Float>(upper_max,
                                  UInt32(code) * NODE_STRIDE + dr::gather<UInt32>(m_background_layers, pair),
                                  upper),
                bound.at(UInt32(-1 - code), !upper));
            bg = dr::maximum(bg, dr::max(layer));
        }
        dr::scatter(out, bits(bg * factor), m_at.background_slot);
    }

    // ---- The mean bound ------------------------------------------------------------

    /// The voxels of `box` that the cube of 2^log2 voxels at o covers
    static Float64 overlap(const Int32 o[3], uint32_t log2, const Box &box) {
        namespace dr = drjit;
        using Int64 = dr::int64_array_t<Float>;
        Float64 v = 1.0;
        for (int a = 0; a < 3; ++a) {
            const Int64 lo = dr::maximum(Int64(o[a]), dr::opaque<Int64>(box.lo[a])),
                        hi = dr::minimum(Int64(o[a]) + ((int64_t(1) << log2) - 1),
                                         dr::opaque<Int64>(box.hi[a]));
            v *= dr::select(lo > hi, 0.0, Float64(hi - lo + 1));
        }
        return v;
    }

    /// The loader's mean_bound (src/loader/mean_bound.cpp) on the backend:
    /// the finest cell's bound, per voxel of the box
    Float64 mean_bound(const UInt32 &table, const Bounds &bound, const Box &box, float factor,
                       const Float &clamp) const {
        namespace dr = drjit;
        const float unscale = 1.f / factor;
        auto slot = [&](const UInt32 &at, const Mask &active = true) {
            return dr::reinterpret_array<Float>(dr::gather<UInt32>(table, at, active)) * unscale;
        };
        auto word = [&](const UInt32 &at) { return dr::gather<UInt32>(table, at); };
        // (`clamp` opaque: max() changes with every update, and a literal
        // would make every update's kernels new ones, compiled again)
        auto clamped = [&](const Float &b) {
            return Float64(dr::minimum(dr::maximum(b, 0.f), clamp));
        };
        auto uniform = [](const Float &M, const Float &m) { return !(M - m > 0.f); };
        auto origin = [](const Int32 &origins, const UInt32 &i, Int32 o[3]) {
            for (int a = 0; a < 3; ++a)
                o[a] = dr::gather<Int32>(origins, 3u * i + a);
        };
        Float64 sum = dr::zeros<Float64>(1);
        // Upper nodes: one bound, or their entries'
        Mask upper_uniform;
        {
            const UInt32 node = dr::arange<UInt32>(m_uppers);
            const UInt32 at = m_at.upper_slot + UPPER_SLOTS * node;
            const Float M = slot(at);
            Int32 o[3];
            origin(m_upper_origins, node, o);
            sum += dr::sum(dr::select(uniform(M, slot(at + 2u)), clamped(M) * overlap(o, 12, box), 0.0));
        }
        {
            const UInt32 lane = dr::arange<UInt32>(m_uppers * 32768u);
            const UInt32 node = lane >> 15, e = lane & 32767u;
            const UInt32 at = m_at.upper_slot + UPPER_SLOTS * node;
            const Int32 code = dr::gather<Int32>(m_upper_entries, lane);
            const Mask tile = code < 0 && !uniform(slot(at), slot(at + 2u));
            Int32 o[3];
            origin(m_upper_origins, node, o);
            o[0] += Int32(e >> 10) << 7;
            o[1] += Int32((e >> 5) & 31u) << 7;
            o[2] += Int32(e & 31u) << 7;
            const Float b = dr::maximum(bound.at(UInt32(-1 - code), tile), slot(at + 1u, tile));
            sum += dr::sum(dr::select(tile, clamped(b) * overlap(o, 7, box), 0.0));
        }
        // Lower nodes under an upper node of more than one bound: one
        // bound, a brick's, or their entries'
        {
            const UInt32 lane = dr::arange<UInt32>(m_lowers * 4096u);
            const UInt32 node = lane >> 12, e = lane & 4095u;
            const UInt32 x = e >> 8, y = (e >> 4) & 15u, z = e & 15u;
            const UInt32 up = m_at.upper_slot + UPPER_SLOTS * dr::gather<UInt32>(m_lower_parent, node);
            const Mask counted = !uniform(slot(up), slot(up + 2u));
            const UInt32 at = m_at.lower_slot + LOWER_SLOTS * node;
            const UInt32 b = ((x >> 2) << 4) | ((y >> 2) << 2) | (z >> 2);
            const Float M = slot(at), brick = slot(at + LOWER_BRICK_M_SLOT + b);
            const UInt32 qb = (word(at + LOWER_BRICK_FRACTION_SLOT + (b >> 2)) >> (8u * (b & 3u))) & 255u,
                         qe = (word(at + LOWER_ENTRY_FRACTION_SLOT + (e >> 2)) >> (8u * (e & 3u))) & 255u;
            const Float cell = dr::select(
                uniform(M, slot(at + 2u)), M,
                dr::select(uniform(brick, brick_min_of(brick, qb)), brick, child_bound_of(brick, qe)));
            Int32 o[3];
            origin(m_lower_origins, node, o);
            o[0] += Int32(x) << 3;
            o[1] += Int32(y) << 3;
            o[2] += Int32(z) << 3;
            sum += dr::sum(dr::select(counted, clamped(cell) * overlap(o, 3, box), 0.0));
        }
        // Root tiles, and the background beyond them
        double box_volume = 1.0;
        for (int a = 0; a < 3; ++a)
            box_volume *= double(int64_t(box.hi[a]) - box.lo[a] + 1);
        Float64 covered = dr::zeros<Float64>(1);
        if (m_tiles > 0) {
            const UInt32 tile = dr::arange<UInt32>(m_tiles);
            Int32 o[3];
            origin(m_tile_origins, tile, o);
            const Float64 vol = overlap(o, 12, box);
            covered = dr::sum(vol);
            const Mask value = dr::gather<Int32>(m_tile_codes, tile) < 0;
            sum += dr::sum(dr::select(
                value, clamped(slot(m_at.tile_slot + dr::gather<UInt32>(m_tile_index, tile))) * vol, 0.0));
        }
        const Float64 rest = dr::opaque<Float64>(box_volume) - covered;
        sum += dr::select(rest > 0.0,
                          clamped(slot(m_at.background_slot)) * rest, 0.0);
        return sum * dr::opaque<Float64>(1.0 / box_volume);
    }

    uint32_t m_leaf_chunk = 1, m_lower_chunk = 1;
    MajorantTableLayout m_layout;
    /// The layout's numbers as the kernels read them: opaque, so that every
    /// grid runs the same kernels (as literals, each grid's first rebuild
    /// compiled its own: 0.26 s)
    struct {
        UInt32 leaf_begin, leaf_words, lower_slot, upper_slot, tile_slot, background_slot;
    } m_at;
    uint32_t m_ring = 1, m_leaves = 0, m_lowers = 0, m_uppers = 0, m_tiles = 0,
             m_background_index = 0, m_background_pairs = 0;
    Int32 m_lower_entries, m_upper_entries, m_lower_around, m_upper_around, m_tile_codes,
        m_tile_around, m_background_codes;
    UInt32 m_tile_index, m_background_layers;
    Int32 m_lower_origins, m_upper_origins, m_tile_origins;
    UInt32 m_lower_parent, m_lower_slow, m_upper_slow;
    std::vector<uint32_t> m_lower_slow_begin; ///< per chunk of lower nodes, its first slow entry
    mutable KernelReplay m_replay, m_mean_replay;
};

} // namespace nanovdb_drjit
